// Serves the simulated power meter to other processes on 127.0.0.1 over the USBTMC socket
// transport (its wire format in docs/source_monitor.md; the client is backends/usbtmc_socket.h):
// libusb cannot present a fake USB device, so the daemon's driver reaches gonio-sim's meter below
// the USBTMC framing instead of below libusb.
#pragma once

#include <atomic>
#include <memory>
#include <thread>

#include "common/result.h"
#include "devices/usbtmc_transport.h"

namespace gonio::sim {

class MonitorSocketServer {
 public:
  // Binds 127.0.0.1:port (0: any free port). The device must outlive the server.
  static Result<std::unique_ptr<MonitorSocketServer>> Start(devices::UsbTmcTransport& device,
                                                            int port = 0);
  ~MonitorSocketServer();
  MonitorSocketServer(const MonitorSocketServer&) = delete;
  MonitorSocketServer& operator=(const MonitorSocketServer&) = delete;
  int port() const { return port_; }

 private:
  explicit MonitorSocketServer(devices::UsbTmcTransport& device) : device_(device) {}
  void Loop();
  devices::UsbTmcTransport& device_;
  int listen_fd_ = -1, port_ = 0;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace gonio::sim
