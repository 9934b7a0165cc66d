// HTTP on a raw loopback socket, for what a client library hides: a request whose body never
// comes, and a connection left open (an event-stream client). Used by tests and benchmarks.
#pragma once

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdint>
#include <string>

namespace gonio::testing {

// A connected socket to 127.0.0.1:port with a 5 s receive timeout, or -1.
inline int ConnectLoopback(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return -1;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  timeval tv{5, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

// Sends `request` on a new connection and returns everything the server sends until it closes
// the connection ("" on a failure to connect; what came, if it does not close within 5 s).
inline std::string RawExchange(int port, const std::string& request) {
  const int fd = ConnectLoopback(port);
  if (fd < 0) return "";
  std::string out;
  if (::send(fd, request.data(), request.size(), 0) == static_cast<ssize_t>(request.size())) {
    char buf[4096];
    for (ssize_t n; (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) out.append(buf, n);
  }
  ::close(fd);
  return out;
}

// An event-stream client: GET /api/v1/events, the reply's status line read, the socket left
// open (closed by the destructor).
struct EventStreamClient {
  int fd = -1;
  std::string status_line;
  explicit EventStreamClient(int port) : fd(ConnectLoopback(port)) {
    const std::string req = "GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
    if (fd < 0 || ::send(fd, req.data(), req.size(), 0) != static_cast<ssize_t>(req.size())) return;
    char c = 0;
    while (::recv(fd, &c, 1, 0) == 1 && c != '\n') status_line += c;
  }
  ~EventStreamClient() {
    if (fd >= 0) ::close(fd);
  }
  EventStreamClient(const EventStreamClient&) = delete;
  EventStreamClient& operator=(const EventStreamClient&) = delete;
  bool admitted() const { return status_line.rfind("HTTP/1.1 200", 0) == 0; }
};

}  // namespace gonio::testing
