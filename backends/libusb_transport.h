// The USBTMC transport on a real USB bus (libusb-1.0): the meter is found by vendor and product
// id (and serial, when several are plugged in), a kernel driver bound to it (usbtmc) is detached,
// its USBTMC interface (class 0xFE, subclass 0x03) claimed, and its bulk endpoints used as they
// are. Not exercised in CI: it needs the device (CTest label "hardware").
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "devices/usbtmc_transport.h"

struct libusb_context;
struct libusb_device_handle;

namespace gonio::backends {

using devices::UsbDeviceId;
using devices::UsbTmcTransport;

class LibUsbTmcTransport final : public UsbTmcTransport {
 public:
  // Errors: kNotConnected (no such device, or no USB access in this environment), kIo (access
  // denied: the message says which udev rule is missing).
  static Result<std::unique_ptr<LibUsbTmcTransport>> Open(UsbDeviceId id);
  ~LibUsbTmcTransport() override;

  Status BulkOut(const std::uint8_t* data, std::size_t n, int timeout_ms) override;
  Result<std::size_t> BulkIn(std::uint8_t* data, std::size_t capacity, int timeout_ms) override;
  Result<std::vector<std::uint8_t>> ClassRequest(std::uint8_t request, std::uint16_t value,
                                                 std::uint16_t length, int timeout_ms) override;
  Status ClearHalt(devices::UsbTmcEndpoint endpoint) override;
  Status Reopen() override;

 private:
  LibUsbTmcTransport() = default;
  Status Find();
  void Close();

  UsbDeviceId id_;
  libusb_context* ctx_ = nullptr;
  libusb_device_handle* handle_ = nullptr;
  int interface_ = -1;
  std::uint8_t ep_in_ = 0, ep_out_ = 0;
};

}  // namespace gonio::backends
