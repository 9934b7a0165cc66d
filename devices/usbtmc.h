// USBTMC message framing over a UsbTmcTransport (USBTMC 1.0 section 3.2, docs/reference.md section
// 4): a 12-byte bulk header (MsgID, bTag, ~bTag, little-endian TransferSize, EOM), payload padded
// to 4 bytes, bTag cycling 1..255, and recovery from a timed-out read with the class abort request.
// The same code runs over libusb and over the simulated meter.
#pragma once

#include <array>
#include <cstdint>
#include <string>

#include "common/result.h"
#include "devices/usbtmc_transport.h"

namespace gonio::devices {

namespace usbtmc_msg {
inline constexpr std::uint8_t kDevDepMsgOut = 1;
inline constexpr std::uint8_t kRequestDevDepMsgIn = 2;  // also the MsgID of DEV_DEP_MSG_IN
inline constexpr std::size_t kHeaderSize = 12;
}  // namespace usbtmc_msg

// The 12-byte header of a bulk-out message.
std::array<std::uint8_t, 12> UsbTmcHeader(std::uint8_t msg_id, std::uint8_t tag,
                                          std::uint32_t transfer_size, bool eom);

class UsbTmc {
 public:
  explicit UsbTmc(UsbTmcTransport& transport, int timeout_ms = 1000)
      : t_(transport), timeout_ms_(timeout_ms) {}

  // Sends one SCPI message (a newline is appended).
  Status Write(const std::string& message);
  // Requests and reads one response, whole (several transfers if long), trailing newline removed.
  // On a timeout the bulk-in transfer is aborted with INITIATE_ABORT_BULK_IN so that the next
  // exchange starts clean, and kTimeout is returned.
  Result<std::string> Read();
  Result<std::string> Query(const std::string& message);
  // INITIATE_CLEAR, then CHECK_CLEAR_STATUS until done (draining bulk-in while the device asks
  // for it), then the bulk-out endpoint's halt cleared (USBTMC 1.0 sections 4.2.1.6-7): the
  // device's buffers emptied and the next message accepted.
  Status Clear();
  // After the device left the bus: reopen it through the transport.
  Status Reopen() { return t_.Reopen(); }

  std::uint8_t last_tag() const { return tag_; }

 private:
  std::uint8_t NextTag();
  Status AbortBulkIn(std::uint8_t tag);

  UsbTmcTransport& t_;
  int timeout_ms_;
  std::uint8_t tag_ = 0;
};

}  // namespace gonio::devices
