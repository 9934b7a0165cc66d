#include "backends/usbtmc_socket.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <memory>

namespace gonio::backends {

namespace {

bool WriteAll(int fd, const std::uint8_t* p, std::size_t n) {
  while (n > 0) {
    const ssize_t w = send(fd, p, n, MSG_NOSIGNAL);
    if (w <= 0) return false;
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

// Reads exactly n bytes, waiting at most timeout_ms for each chunk (< 0: forever).
bool ReadAll(int fd, std::uint8_t* p, std::size_t n, int timeout_ms) {
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

void PutU32(std::vector<std::uint8_t>& v, std::uint32_t x) {
  for (int k = 0; k < 4; ++k) v.push_back(static_cast<std::uint8_t>(x >> (8 * k)));
}
std::uint32_t GetU32(const std::uint8_t* p) {
  return p[0] | (std::uint32_t(p[1]) << 8) | (std::uint32_t(p[2]) << 16) |
         (std::uint32_t(p[3]) << 24);
}

bool SendFrame(int fd, std::uint8_t head, const std::vector<std::uint8_t>& body) {
  std::vector<std::uint8_t> out{head};
  PutU32(out, static_cast<std::uint32_t>(body.size()));
  out.insert(out.end(), body.begin(), body.end());
  return WriteAll(fd, out.data(), out.size());
}

constexpr std::uint32_t kMaxFrame = 1 << 20;

}  // namespace

Result<std::unique_ptr<UsbTmcSocketTransport>> UsbTmcSocketTransport::Connect(
    const std::string& host, int port) {
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  if (inet_pton(AF_INET, host.c_str(), &addr.sin_addr) != 1)
    return Error{ErrorCode::kInvalidArgument,
                 "source monitor socket: '" + host + "' is not a numeric IPv4 address"};
  std::unique_ptr<UsbTmcSocketTransport> t(new UsbTmcSocketTransport());
  t->host_ = host;
  t->port_ = port;
  if (Status s = t->Dial(); !s.ok()) return s.error();
  return t;
}

Status UsbTmcSocketTransport::Dial() {
  if (fd_ >= 0) close(fd_);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port_));
  inet_pton(AF_INET, host_.c_str(), &addr.sin_addr);  // checked by Connect
  fd_ = socket(AF_INET, SOCK_STREAM, 0);
  if (fd_ < 0) return Error{ErrorCode::kIo, std::string("socket: ") + std::strerror(errno)};
  if (connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0)
    return Error{ErrorCode::kNotConnected, "source monitor socket " + host_ + ":" +
                                               std::to_string(port_) + ": " + std::strerror(errno)};
  const int one = 1;
  setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  return OkStatus();
}

UsbTmcSocketTransport::~UsbTmcSocketTransport() {
  if (fd_ >= 0) close(fd_);
}

Result<std::vector<std::uint8_t>> UsbTmcSocketTransport::Call(
    char op, const std::vector<std::uint8_t>& payload, int timeout_ms) {
  if (!SendFrame(fd_, static_cast<std::uint8_t>(op), payload))
    return Error{ErrorCode::kNotConnected, "source monitor socket closed"};
  // The device answers within its own timeout; allow the socket a second more.
  std::uint8_t head[5];
  if (!ReadAll(fd_, head, 5, timeout_ms + 1000))
    return Error{ErrorCode::kNotConnected, "source monitor socket: no reply"};
  const std::uint32_t n = GetU32(head + 1);
  if (n > kMaxFrame) return Error{ErrorCode::kProtocol, "source monitor socket: oversized reply"};
  std::vector<std::uint8_t> body(n);
  if (n > 0 && !ReadAll(fd_, body.data(), n, timeout_ms + 1000))
    return Error{ErrorCode::kNotConnected, "source monitor socket: truncated reply"};
  if (head[0] != 0)
    return Error{static_cast<ErrorCode>(head[0] - 1), std::string(body.begin(), body.end())};
  return body;
}

Status UsbTmcSocketTransport::BulkOut(const std::uint8_t* data, std::size_t n, int timeout_ms) {
  auto r = Call('O', std::vector<std::uint8_t>(data, data + n), timeout_ms);
  if (!r.ok()) return r.error();
  return OkStatus();
}

Result<std::size_t> UsbTmcSocketTransport::BulkIn(std::uint8_t* data, std::size_t capacity,
                                                  int timeout_ms) {
  std::vector<std::uint8_t> p;
  PutU32(p, static_cast<std::uint32_t>(capacity));
  auto r = Call('I', p, timeout_ms);
  if (!r.ok()) return r.error();
  if (r->size() > capacity) return Error{ErrorCode::kProtocol, "bulk-in beyond capacity"};
  std::memcpy(data, r->data(), r->size());
  return r->size();
}

Result<std::vector<std::uint8_t>> UsbTmcSocketTransport::ClassRequest(std::uint8_t request,
                                                                      std::uint16_t value,
                                                                      std::uint16_t length,
                                                                      int timeout_ms) {
  const std::vector<std::uint8_t> p{
      request, static_cast<std::uint8_t>(value & 0xFF), static_cast<std::uint8_t>(value >> 8),
      static_cast<std::uint8_t>(length & 0xFF), static_cast<std::uint8_t>(length >> 8)};
  return Call('C', p, timeout_ms);
}

Status UsbTmcSocketTransport::ClearHalt(devices::UsbTmcEndpoint endpoint) {
  const std::uint8_t e = endpoint == devices::UsbTmcEndpoint::kBulkOut ? 0 : 1;
  auto r = Call('H', {e}, 1000);
  if (!r.ok()) return r.error();
  return OkStatus();
}

Status UsbTmcSocketTransport::Reopen() {
  auto r = Call('R', {}, 1000);
  if (!r.ok() && r.error().code == ErrorCode::kNotConnected) {
    // The socket is gone with the process that served it: dial again, then reopen the device.
    if (Status s = Dial(); !s.ok()) return s;
    r = Call('R', {}, 1000);
  }
  if (!r.ok()) return r.error();
  return OkStatus();
}

}  // namespace gonio::backends
