// USBTMC transfers carried over a loopback TCP socket: how a USBTMC device that is not on a USB
// bus - the simulated meter inside gonio-sim - reaches a driver in another process. It carries
// the transport layer's calls (bulk-out, bulk-in, class request, reopen) one for one, below the
// USBTMC framing, so the framing code is the same as over libusb.
//
// Wire format (docs/source_monitor.md; gonio-sim serves it on its own; all integers little-endian):
// a request is op (1 byte: 'O' bulk-out, 'I' bulk-in, 'C' class request, 'H' clear halt, 'R'
// reopen), length (u32) and that many bytes: the bulk-out data; the bulk-in capacity (u32);
// request (u8), value (u16), length (u16); the endpoint (u8: 0 bulk-out, 1 bulk-in). A reply is a
// code (1 byte: 0 success, otherwise 1 + the ErrorCode), length (u32) and the bytes: data on
// success, the error message otherwise.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "common/result.h"
#include "devices/usbtmc_transport.h"

namespace gonio::backends {

using devices::UsbTmcTransport;

// The client side: connects to 127.0.0.1:port (a numeric loopback address only).
class UsbTmcSocketTransport final : public UsbTmcTransport {
 public:
  static Result<std::unique_ptr<UsbTmcSocketTransport>> Connect(const std::string& host, int port);
  ~UsbTmcSocketTransport() override;

  Status BulkOut(const std::uint8_t* data, std::size_t n, int timeout_ms) override;
  Result<std::size_t> BulkIn(std::uint8_t* data, std::size_t capacity, int timeout_ms) override;
  Result<std::vector<std::uint8_t>> ClassRequest(std::uint8_t request, std::uint16_t value,
                                                 std::uint16_t length, int timeout_ms) override;
  Status ClearHalt(devices::UsbTmcEndpoint endpoint) override;
  // The device reopened; when the socket itself has gone (gonio-sim restarted), it is connected
  // again to the same address first.
  Status Reopen() override;

 private:
  UsbTmcSocketTransport() = default;
  Status Dial();  // a new socket to host_:port_ in fd_ (the old one closed)
  std::string host_;
  int port_ = 0;
  Result<std::vector<std::uint8_t>> Call(char op, const std::vector<std::uint8_t>& payload,
                                         int timeout_ms);
  int fd_ = -1;
};

}  // namespace gonio::backends
