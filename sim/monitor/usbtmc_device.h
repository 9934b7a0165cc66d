// The device side of USBTMC, written from the USBTMC 1.0 specification (docs/reference.md
// section 4) and not from our driver's framing (devices/usbtmc.h): the simulated meter parses and
// builds the bytes on its own, so that a framing bug in the driver shows up as a disagreement
// instead of being shared by both sides.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

namespace gonio::sim::usbtmc {

// MsgID values of the bulk headers (USBTMC 1.0 table 2).
inline constexpr std::uint8_t kDevDepMsgOut = 1;
inline constexpr std::uint8_t kRequestDevDepMsgIn = 2;
inline constexpr std::uint8_t kDevDepMsgIn = 2;  // the Bulk-IN MsgID (table 8)

// Every bulk transfer starts with a 12-byte header (section 3.2): MsgID, bTag, ~bTag, a reserved
// byte, TransferSize (little-endian u32), bmTransferAttributes (bit 0: EOM) and 3 reserved bytes.
inline constexpr std::size_t kHeaderBytes = 12;
inline constexpr std::size_t kTransferSizeAt = 4;
inline constexpr std::size_t kAttributesAt = 8;
inline constexpr std::uint8_t kEom = 0x01;

// bRequest of the class-specific requests (table 15).
inline constexpr std::uint8_t kInitiateAbortBulkOut = 1;
inline constexpr std::uint8_t kCheckAbortBulkOutStatus = 2;
inline constexpr std::uint8_t kInitiateAbortBulkIn = 3;
inline constexpr std::uint8_t kCheckAbortBulkInStatus = 4;
inline constexpr std::uint8_t kInitiateClear = 5;
inline constexpr std::uint8_t kCheckClearStatus = 6;
inline constexpr std::uint8_t kGetCapabilities = 7;

// USBTMC_status (table 16).
inline constexpr std::uint8_t kStatusSuccess = 0x01;
inline constexpr std::uint8_t kStatusFailed = 0x80;

// A bulk-out header is well formed when it is long enough and bTagInverse is bTag's complement
// (table 1: bTag is never 0).
inline bool ValidHeader(const std::uint8_t* h, std::size_t n) {
  return n >= kHeaderBytes && h[1] != 0 && h[2] == static_cast<std::uint8_t>(~h[1]);
}

inline std::uint32_t TransferSize(const std::uint8_t* h) {
  std::uint32_t size = 0;
  for (std::size_t k = 0; k < 4; ++k) size |= std::uint32_t(h[kTransferSizeAt + k]) << (8 * k);
  return size;
}

// The header of a DEV_DEP_MSG_IN transfer carrying `size` bytes (table 9).
inline std::array<std::uint8_t, kHeaderBytes> DevDepMsgInHeader(std::uint8_t tag,
                                                                std::uint32_t size, bool eom) {
  std::array<std::uint8_t, kHeaderBytes> h{};
  h[0] = kDevDepMsgIn;
  h[1] = tag;
  h[2] = static_cast<std::uint8_t>(~tag);
  for (std::size_t k = 0; k < 4; ++k) h[kTransferSizeAt + k] = std::uint8_t(size >> (8 * k));
  h[kAttributesAt] = eom ? kEom : 0;
  return h;
}

}  // namespace gonio::sim::usbtmc
