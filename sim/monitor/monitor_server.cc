#include "sim/monitor/monitor_server.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <string>
#include <vector>

namespace gonio::sim {

namespace {

// The socket transport's wire format (docs/source_monitor.md, "The socket transport"), served
// here from that description and not from the driver's client: a request is op (1 byte), a
// little-endian u32 length and that many bytes; a reply is a code (0 success, else 1 + the
// ErrorCode), a u32 length and the data or the error's message.
constexpr std::uint32_t kMaxRequest = 1 << 20;

bool WriteAll(int fd, const std::uint8_t* p, std::size_t n) {
  while (n > 0) {
    const ssize_t w = send(fd, p, n, MSG_NOSIGNAL);
    if (w <= 0) return false;
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

// Exactly n bytes, waiting at most timeout_ms for each chunk.
bool ReadExactly(int fd, std::uint8_t* p, std::size_t n, int timeout_ms) {
  while (n > 0) {
    pollfd pfd{fd, POLLIN, 0};
    if (poll(&pfd, 1, timeout_ms) <= 0) return false;
    const ssize_t r = recv(fd, p, n, 0);
    if (r <= 0) return false;
    p += r;
    n -= static_cast<std::size_t>(r);
  }
  return true;
}

std::uint32_t LittleU32(const std::uint8_t* p) {
  return std::uint32_t(p[0]) | std::uint32_t(p[1]) << 8 | std::uint32_t(p[2]) << 16 |
         std::uint32_t(p[3]) << 24;
}
std::uint16_t LittleU16(const std::uint8_t* p) {
  return static_cast<std::uint16_t>(p[0] | p[1] << 8);
}

bool Reply(int fd, const Error* e, const std::vector<std::uint8_t>& data) {
  std::vector<std::uint8_t> out;
  out.push_back(e == nullptr ? 0 : static_cast<std::uint8_t>(static_cast<int>(e->code) + 1));
  const std::vector<std::uint8_t> body =
      e == nullptr ? data : std::vector<std::uint8_t>(e->message.begin(), e->message.end());
  const auto n = static_cast<std::uint32_t>(body.size());
  for (int k = 0; k < 4; ++k) out.push_back(static_cast<std::uint8_t>(n >> (8 * k)));
  out.insert(out.end(), body.begin(), body.end());
  return WriteAll(fd, out.data(), out.size());
}

bool ReplyStatus(int fd, const Status& s) { return Reply(fd, s.ok() ? nullptr : &s.error(), {}); }

// One request from fd, answered by the device. False: the peer left or broke the format.
bool ServeOne(int fd, devices::UsbTmcTransport& device) {
  std::uint8_t head[5];
  if (!ReadExactly(fd, head, sizeof head, 1000)) return false;
  const std::uint32_t n = LittleU32(head + 1);
  if (n > kMaxRequest) return false;
  std::vector<std::uint8_t> body(n);
  if (n > 0 && !ReadExactly(fd, body.data(), n, 5000)) return false;
  constexpr int kTimeoutMs = 1000;
  switch (head[0]) {
    case 'O':
      return ReplyStatus(fd, device.BulkOut(body.data(), body.size(), kTimeoutMs));
    case 'I': {
      if (n != 4) return false;
      std::vector<std::uint8_t> buf(std::min(LittleU32(body.data()), kMaxRequest));
      auto r = device.BulkIn(buf.data(), buf.size(), kTimeoutMs);
      if (!r.ok()) return Reply(fd, &r.error(), {});
      buf.resize(*r);
      return Reply(fd, nullptr, buf);
    }
    case 'C': {
      if (n != 5) return false;
      auto r = device.ClassRequest(body[0], LittleU16(&body[1]), LittleU16(&body[3]), kTimeoutMs);
      return r.ok() ? Reply(fd, nullptr, *r) : Reply(fd, &r.error(), {});
    }
    case 'H':
      if (n != 1 || body[0] > 1) return false;
      return ReplyStatus(fd, device.ClearHalt(body[0] == 0 ? devices::UsbTmcEndpoint::kBulkOut
                                                           : devices::UsbTmcEndpoint::kBulkIn));
    case 'R':
      return ReplyStatus(fd, device.Reopen());
    default:
      return false;
  }
}

}  // namespace

Result<std::unique_ptr<MonitorSocketServer>> MonitorSocketServer::Start(
    devices::UsbTmcTransport& device, int port) {
  std::unique_ptr<MonitorSocketServer> s(new MonitorSocketServer(device));
  s->listen_fd_ = socket(AF_INET, SOCK_STREAM, 0);
  if (s->listen_fd_ < 0)
    return Error{ErrorCode::kIo, std::string("socket: ") + std::strerror(errno)};
  const int one = 1;
  setsockopt(s->listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);  // loopback only (docs/design.md network rules)
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
      if (!ServeOne(fds[k].fd, device_)) {
        close(fds[k].fd);
        std::erase(clients, fds[k].fd);
      }
    }
  }
  for (int fd : clients) close(fd);
}

}  // namespace gonio::sim
