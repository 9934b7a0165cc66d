// The byte level below the USBTMC framing: one bulk-out and one bulk-in endpoint and the class's
// control requests, as libusb presents a USBTMC interface (USBTMC 1.0, sections 3 and 4). The
// libusb backend implements it for a real meter; the simulated meter (sim/monitor) implements it
// in-process, because libusb cannot present a fake device. The framing (usbtmc.h) is the same
// code over either.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "common/result.h"

namespace gonio::devices {

// USBTMC class-specific requests (bRequest), USBTMC 1.0 table 15.
namespace usbtmc_request {
inline constexpr std::uint8_t kInitiateAbortBulkOut = 1;
inline constexpr std::uint8_t kCheckAbortBulkOutStatus = 2;
inline constexpr std::uint8_t kInitiateAbortBulkIn = 3;
inline constexpr std::uint8_t kCheckAbortBulkInStatus = 4;
inline constexpr std::uint8_t kInitiateClear = 5;
inline constexpr std::uint8_t kCheckClearStatus = 6;
inline constexpr std::uint8_t kGetCapabilities = 7;
}  // namespace usbtmc_request

// USBTMC_status values (USBTMC 1.0 table 16).
inline constexpr std::uint8_t kUsbTmcStatusSuccess = 0x01;
inline constexpr std::uint8_t kUsbTmcStatusPending = 0x02;
inline constexpr std::uint8_t kUsbTmcStatusFailed = 0x80;

// A bulk endpoint, for ClearHalt.
enum class UsbTmcEndpoint { kBulkOut, kBulkIn };

// A USB device to open: what the libusb transport (backends/libusb_transport.h) looks for.
struct UsbDeviceId {
  std::uint16_t vendor_id = 0x1313;   // Thorlabs
  std::uint16_t product_id = 0x8072;  // PM100USB
  std::string serial;                 // empty: the only one present
};

class UsbTmcTransport {
 public:
  virtual ~UsbTmcTransport() = default;
  // One bulk-out transfer of n bytes. Errors: kTimeout, kNotConnected (the device left the bus),
  // kIo.
  virtual Status BulkOut(const std::uint8_t* data, std::size_t n, int timeout_ms) = 0;
  // One bulk-in transfer of at most `capacity` bytes; the bytes received. Errors as BulkOut.
  virtual Result<std::size_t> BulkIn(std::uint8_t* data, std::size_t capacity, int timeout_ms) = 0;
  // A class request to the interface (or the bulk-in/out endpoint for the abort requests): the
  // device's response of at most `length` bytes (its first byte a USBTMC_status).
  virtual Result<std::vector<std::uint8_t>> ClassRequest(std::uint8_t request, std::uint16_t value,
                                                         std::uint16_t length, int timeout_ms) = 0;
  // USB 2.0 CLEAR_FEATURE(ENDPOINT_HALT) on a bulk endpoint: what the host sends after a clear
  // (USBTMC 1.0 sections 4.2.1.6-7: INITIATE_CLEAR halts the bulk-out endpoint) or a stall.
  virtual Status ClearHalt(UsbTmcEndpoint endpoint) = 0;
  // After kNotConnected: find the device again (same vendor, product and serial) and claim it.
  virtual Status Reopen() = 0;
};

}  // namespace gonio::devices
