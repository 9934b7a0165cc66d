#include "sim/monitor/monitor_server.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>
#include <vector>

#include "drivers/monitor/usbtmc_socket.h"

namespace gonio::sim {

Result<std::unique_ptr<MonitorSocketServer>> MonitorSocketServer::Start(
    drivers::UsbTmcTransport& device, int port) {
  std::unique_ptr<MonitorSocketServer> s(new MonitorSocketServer(device));
  s->listen_fd_ = socket(AF_INET, SOCK_STREAM, 0);
  if (s->listen_fd_ < 0)
    return Error{ErrorCode::kIo, std::string("socket: ") + std::strerror(errno)};
  const int one = 1;
  setsockopt(s->listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);  // loopback only (DESIGN.md network rules)
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  if (bind(s->listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      listen(s->listen_fd_, 4) != 0)
    return Error{ErrorCode::kIo, "source monitor: cannot listen on 127.0.0.1:" +
                                     std::to_string(port) + ": " + std::strerror(errno)};
  socklen_t len = sizeof addr;
  getsockname(s->listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len);
  s->port_ = ntohs(addr.sin_port);
  s->thread_ = std::thread([p = s.get()] { p->Loop(); });
  return s;
}

MonitorSocketServer::~MonitorSocketServer() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) close(listen_fd_);
}

void MonitorSocketServer::Loop() {
  std::vector<int> clients;
  while (!stop_) {
    std::vector<pollfd> fds{{listen_fd_, POLLIN, 0}};
    for (int fd : clients) fds.push_back({fd, POLLIN, 0});
    if (poll(fds.data(), fds.size(), 50) <= 0) continue;  // 50 ms: notice stop_
    if (fds[0].revents & POLLIN) {
      const int fd = accept(listen_fd_, nullptr, nullptr);
      if (fd >= 0) clients.push_back(fd);
    }
    for (std::size_t k = 1; k < fds.size(); ++k) {
      if (!(fds[k].revents & (POLLIN | POLLHUP | POLLERR))) continue;
      if (!drivers::ServeOneUsbTmcCall(fds[k].fd, device_)) {
        close(fds[k].fd);
        std::erase(clients, fds[k].fd);
      }
    }
  }
  for (int fd : clients) close(fd);
}

}  // namespace gonio::sim
