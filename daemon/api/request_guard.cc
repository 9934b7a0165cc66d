#include "daemon/api/request_guard.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <list>
#include <nlohmann/json.hpp>
#include <optional>
#include <string_view>
#include <thread>
#include <vector>

namespace gonio::daemon {
namespace {

using Clock = std::chrono::steady_clock;
constexpr std::size_t kInFlight = 64 * 1024;  // each direction's bytes held at most
// After a refusal the client may still be sending (a body over the bound, the rest of a 200 MB
// line): its bytes are read and dropped for a moment, so that closing does not reset the
// connection before the refusal is read (a client sending a 5 MB body reads its 413), then the
// connection is closed whatever is left. Dropped bytes cost time, not memory.
constexpr std::size_t kDrainBytes = 16u << 20;
constexpr double kDrainS = 2.0;
constexpr int kPollMs = 100;  // the loop's tick: timeouts are checked this often

enum class Phase { kHead, kForward, kRefused };

struct Connection {
  int client = -1, upstream = -1;
  Phase phase = Phase::kHead;
  Clock::time_point accepted;
  std::string head;         // kHead: what has arrived of the request head
  std::string to_upstream;  // kForward: bytes to pass on (the head, then the body's)
  std::string to_client;    // the response, or the refusal
  std::size_t body_left = 0;
  bool client_done = false;  // the client sent all it may (its body is whole)
  // The client closed its side. Passed on (SHUT_WR) only if the server has said nothing for a
  // tick after it: a server still reading what it takes for an unfinished request then ends it
  // at once, as it would for a direct client; one that has begun to answer is left alone
  // (cpp-httplib takes a read end as a client gone and drops an event stream's reply).
  bool client_eof = false;
  Clock::time_point eof_at;
  bool upstream_shut = false;
  bool answered = false;       // a byte of the response has come
  bool upstream_done = false;  // the server's response is over
  Clock::time_point drain_until;
  std::size_t drained = 0;
};

void NonBlocking(int fd) { ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) | O_NONBLOCK); }

double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

const char* Reason(int status) {
  switch (status) {
    case 400:
      return "Bad Request";
    case 408:
      return "Request Timeout";
    case 411:
      return "Length Required";
    case 413:
      return "Payload Too Large";
    case 414:
      return "URI Too Long";
    case 431:
      return "Request Header Fields Too Large";
    default:
      return "Service Unavailable";
  }
}

const char* Code(int status) {
  switch (status) {
    case 400:
    case 411:
      return "bad_request";
    case 408:
      return "timeout";
    case 413:
    case 414:
    case 431:
      return "too_large";
    default:
      return "unavailable";
  }
}

std::string RefusalText(int status, const std::string& message) {
  const std::string body =
      nlohmann::json{{"error", {{"code", Code(status)}, {"message", message}}}}.dump();
  return "HTTP/1.1 " + std::to_string(status) + " " + Reason(status) +
         "\r\nContent-Type: application/json\r\nContent-Length: " + std::to_string(body.size()) +
         "\r\nConnection: close\r\n\r\n" + body;
}

bool IEquals(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::tolower(static_cast<unsigned char>(x)) ==
                  std::tolower(static_cast<unsigned char>(y));
         });
}

std::string_view Trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
    s.remove_suffix(1);
  return s;
}

// What a whole head asks for: a refusal (status and message), or the body's length.
struct HeadVerdict {
  int status = 0;  // 0: within bounds
  std::string message;
  std::size_t body_bytes = 0;
};

HeadVerdict JudgeHead(std::string_view head, const GuardLimits& l) {
  HeadVerdict v;
  int headers = 0;
  std::size_t pos = head.find('\n') + 1;  // past the request line (checked as it arrived)
  while (pos < head.size()) {
    const std::size_t end = head.find('\n', pos);
    std::string_view line =
        head.substr(pos, (end == std::string_view::npos ? head.size() : end) - pos);
    pos = end == std::string_view::npos ? head.size() : end + 1;
    line = Trim(line);
    if (line.empty()) break;  // the blank line that ends the head
    if (++headers > l.max_headers) {
      v.status = 431;
      v.message = "more than " + std::to_string(l.max_headers) + " headers";
      return v;
    }
    const std::size_t colon = line.find(':');
    if (colon == std::string_view::npos) continue;  // cpp-httplib judges the syntax
    const std::string_view name = Trim(line.substr(0, colon));
    const std::string_view value = Trim(line.substr(colon + 1));
    if (IEquals(name, "Transfer-Encoding")) {
      v.status = 411;
      v.message = "a body must declare its Content-Length (no Transfer-Encoding)";
      return v;
    }
    if (IEquals(name, "Content-Length")) {
      std::size_t n = 0;
      bool digits = !value.empty() && value.size() <= 19;
      for (char c : value) {
        if (c < '0' || c > '9') {
          digits = false;
          break;
        }
        n = n * 10 + static_cast<std::size_t>(c - '0');
      }
      if (!digits) {
        v.status = 400;
        v.message = "Content-Length is not a number of bytes";
        return v;
      }
      if (n > l.max_body_bytes) {
        v.status = 413;
        v.message = "the body is larger than " + std::to_string(l.max_body_bytes) + " bytes";
        return v;
      }
      v.body_bytes = n;
    }
  }
  return v;
}

}  // namespace

struct RequestGuard::Impl {
  GuardLimits limits;
  std::string upstream_path;
  int listener = -1;
  int port = 0;
  int wake[2] = {-1, -1};  // Stop() writes a byte: the loop leaves poll at once
  std::atomic<bool> stopping{false};
  std::list<Connection> connections;
  std::thread thread;

  ~Impl() {
    for (int fd : {listener, wake[0], wake[1]})
      if (fd >= 0) ::close(fd);
  }

  void Close(Connection& c) {
    if (c.client >= 0) ::close(c.client);
    if (c.upstream >= 0) ::close(c.upstream);
    c.client = c.upstream = -1;
  }

  void Refuse(Connection& c, int status, const std::string& message) {
    if (c.upstream >= 0) ::close(c.upstream);
    c.upstream = -1;
    c.phase = Phase::kRefused;
    c.head.clear();
    c.head.shrink_to_fit();
    c.to_upstream.clear();
    c.to_client = RefusalText(status, message);
    c.drain_until = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                       std::chrono::duration<double>(kDrainS));
  }

  // The head is whole and within bounds: open the server's socket and pass it on.
  void Forward(Connection& c, std::size_t head_end, std::size_t body_bytes) {
    const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, upstream_path.c_str(), sizeof addr.sun_path - 1);
    if (fd < 0 || ::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
      if (fd >= 0) ::close(fd);
      return Refuse(c, 503, "goniod's HTTP server does not answer (goniod's log says why)");
    }
    NonBlocking(fd);
    c.upstream = fd;
    c.phase = Phase::kForward;
    // Body bytes that came with the head: as many as declared (keep-alive is off: a second
    // request on the connection is not passed on).
    const std::size_t extra = std::min(c.head.size() - head_end, body_bytes);
    c.to_upstream = c.head.substr(0, head_end + extra);
    c.body_left = body_bytes - extra;
    c.client_done = c.body_left == 0;
    c.head.clear();
    c.head.shrink_to_fit();
    // At once, not at the loop's next turn: the server's thread is already waiting for it.
    if (!Write(c.upstream, c.to_upstream))
      Refuse(c, 503, "goniod's HTTP server closed the request");
  }

  // kHead: new bytes judged as they arrive.
  void OnHeadBytes(Connection& c) {
    const std::size_t line_end = c.head.find('\n');
    if (line_end == std::string::npos ? c.head.size() > limits.max_request_line
                                      : line_end > limits.max_request_line)
      return Refuse(
          c, 414,
          "the request line is longer than " + std::to_string(limits.max_request_line) + " bytes");
    // The head ends where cpp-httplib's does: a blank line after CRLF (a bare LF ends no line
    // there, and a head judged whole here that it does not take as whole would wait its time).
    const std::size_t end = c.head.find("\r\n\r\n");
    const std::size_t head_end = end == std::string::npos ? std::string::npos : end + 4;
    if (head_end == std::string::npos ? c.head.size() > limits.max_head_bytes
                                      : head_end > limits.max_head_bytes)
      return Refuse(
          c, 431,
          "the request's head is longer than " + std::to_string(limits.max_head_bytes) + " bytes");
    if (head_end == std::string::npos) return;
    const HeadVerdict v = JudgeHead(std::string_view(c.head).substr(0, head_end), limits);
    if (v.status != 0) return Refuse(c, v.status, v.message);
    Forward(c, head_end, v.body_bytes);
  }

  // Reads what the client sent into the phase's place; false: the connection is to be closed.
  bool ReadClient(Connection& c) {
    char buf[16384];
    const ssize_t n = ::recv(c.client, buf, sizeof buf, 0);
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    if (n == 0) {
      // The client closed its side: a head never finished, or a forwarded request's response
      // still due.
      if (c.phase != Phase::kForward) return false;
      if (c.body_left > 0) return false;  // the body will never be whole
      c.client_eof = true;
      c.eof_at = Clock::now();
      return true;
    }
    const auto got = static_cast<std::size_t>(n);
    switch (c.phase) {
      case Phase::kHead:
        c.head.append(buf, got);
        OnHeadBytes(c);
        break;
      case Phase::kForward: {  // beyond the declared body: dropped (one request a connection)
        const std::size_t take = std::min(got, c.body_left);
        c.to_upstream.append(buf, take);
        c.body_left -= take;
        if (c.body_left == 0) c.client_done = true;
        break;
      }
      case Phase::kRefused:
        c.drained += got;
        if (c.drained > kDrainBytes) return false;
        break;
    }
    return true;
  }

  bool ReadUpstream(Connection& c) {
    char buf[16384];
    const ssize_t n = ::recv(c.upstream, buf, sizeof buf, 0);
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    if (n == 0) {  // the response is whole: its socket is done with (and no longer polled)
      c.upstream_done = true;
      ::close(c.upstream);
      c.upstream = -1;
      return true;
    }
    c.to_client.append(buf, static_cast<std::size_t>(n));
    c.answered = true;
    return true;
  }

  static bool Write(int fd, std::string& pending) {
    while (!pending.empty()) {
      const ssize_t n = ::send(fd, pending.data(), pending.size(), MSG_NOSIGNAL);
      if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
      pending.erase(0, static_cast<std::size_t>(n));
    }
    return true;
  }

  // Timeouts and the end of a connection's life; true: close it now.
  bool Expired(Connection& c, Clock::time_point now) {
    const double age = Seconds(now - c.accepted);
    if (c.phase == Phase::kHead && age > limits.head_timeout_s) {
      Refuse(c, 408,
             "the request's head did not arrive within " +
                 std::to_string(static_cast<int>(limits.head_timeout_s)) + " s");
      return false;
    }
    if (c.phase == Phase::kForward && !c.client_done && age > limits.request_timeout_s)
      return true;  // a body that trickles: the server has already begun, so no reply is sent
    if (c.phase == Phase::kRefused)
      return (c.to_client.empty() && now > c.drain_until) ||
             now > c.drain_until + std::chrono::seconds(5);
    if (c.phase == Phase::kForward && c.upstream_done && c.to_client.empty()) return true;
    if (c.phase == Phase::kForward && c.client_eof && !c.answered && !c.upstream_shut &&
        c.upstream >= 0 && c.to_upstream.empty() && Seconds(now - c.eof_at) * 1000 >= kPollMs) {
      ::shutdown(c.upstream, SHUT_WR);
      c.upstream_shut = true;
    }
    return false;
  }

  void Accept() {
    while (true) {
      const int fd = ::accept4(listener, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
      if (fd < 0) return;  // EAGAIN: none left; anything else: retried on the next readiness
      if (static_cast<int>(connections.size()) >= limits.max_connections) {
        const std::string busy =
            RefusalText(503, "goniod has " + std::to_string(limits.max_connections) +
                                 " connections open already; try again");
        (void)::send(fd, busy.data(), busy.size(), MSG_NOSIGNAL);
        ::close(fd);
        continue;
      }
      Connection c;
      c.client = fd;
      c.accepted = Clock::now();
      connections.push_back(std::move(c));
    }
  }

  void Loop() {
    std::vector<pollfd> fds;
    std::vector<Connection*> owner;  // per entry of fds past the first two: whose fd
    while (!stopping.load()) {
      fds.clear();
      owner.clear();
      fds.push_back({listener, POLLIN, 0});
      fds.push_back({wake[0], POLLIN, 0});
      for (Connection& c : connections) {
        short client_events = 0;
        // Read from the client while there is room for what it sends (and always while refused:
        // its bytes are dropped); write while a response or a refusal waits.
        if (c.phase == Phase::kRefused || c.phase == Phase::kHead ||
            (!c.client_eof && c.to_upstream.size() < kInFlight))
          client_events |= POLLIN;
        if (!c.to_client.empty()) client_events |= POLLOUT;
        fds.push_back({c.client, client_events, 0});
        owner.push_back(&c);
        if (c.upstream >= 0) {
          short up = 0;
          if (!c.upstream_done && c.to_client.size() < kInFlight) up |= POLLIN;
          if (!c.to_upstream.empty()) up |= POLLOUT;
          fds.push_back({c.upstream, up, 0});
          owner.push_back(&c);
        }
      }
      const int ready = ::poll(fds.data(), fds.size(), kPollMs);
      if (ready < 0 && errno != EINTR) break;
      if (stopping.load()) break;
      std::vector<Connection*> dead;
      for (std::size_t i = 2; i < fds.size(); ++i) {
        Connection& c = *owner[i - 2];
        const pollfd& p = fds[i];
        if (p.revents == 0 || c.client < 0) continue;
        bool ok = true;
        if (p.fd == c.client) {
          if (p.revents & POLLOUT) ok = Write(c.client, c.to_client);
          if (ok && (p.revents & POLLIN)) ok = ReadClient(c);
          if (p.revents & (POLLHUP | POLLERR)) ok = false;  // the client is gone both ways
          if (ok && c.phase == Phase::kRefused && c.to_client.empty())
            ::shutdown(c.client, SHUT_WR);  // the refusal is out: the client sees the end
        } else if (p.fd == c.upstream) {
          if (p.revents & POLLOUT) ok = Write(c.upstream, c.to_upstream);
          if (ok && (p.revents & (POLLIN | POLLHUP | POLLERR))) ok = ReadUpstream(c);
        }

        if (!ok) dead.push_back(&c);
      }
      const auto now = Clock::now();
      for (auto it = connections.begin(); it != connections.end();) {
        const bool is_dead = std::find(dead.begin(), dead.end(), &*it) != dead.end();
        if (is_dead || Expired(*it, now)) {
          Close(*it);
          it = connections.erase(it);
        } else {
          ++it;
        }
      }
      if (fds[0].revents & POLLIN) Accept();
    }
    for (Connection& c : connections) Close(c);
    connections.clear();
  }
};

RequestGuard::RequestGuard(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

Result<std::unique_ptr<RequestGuard>> RequestGuard::Start(const std::string& host, int port,
                                                          const std::string& upstream_path,
                                                          const GuardLimits& limits) {
  auto impl = std::make_unique<Impl>();
  impl->limits = limits;
  impl->upstream_path = upstream_path;
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  if (::inet_pton(AF_INET, host.c_str(), &addr.sin_addr) != 1)
    return Error{ErrorCode::kInvalidArgument,
                 "the API's address '" + host + "' is not a numeric IPv4 address"};
  impl->listener = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  const int one = 1;
  if (impl->listener < 0 ||
      ::setsockopt(impl->listener, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one) != 0 ||
      ::bind(impl->listener, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      ::listen(impl->listener, 128) != 0)
    return Error{ErrorCode::kIo, "cannot bind the API to " + host + ":" + std::to_string(port) +
                                     " (" + std::strerror(errno) + ")"};
  socklen_t len = sizeof addr;
  ::getsockname(impl->listener, reinterpret_cast<sockaddr*>(&addr), &len);
  impl->port = ntohs(addr.sin_port);
  if (::pipe2(impl->wake, O_CLOEXEC | O_NONBLOCK) != 0)
    return Error{ErrorCode::kIo, std::string("the API's guard: pipe: ") + std::strerror(errno)};
  Impl* raw = impl.get();
  impl->thread = std::thread([raw] { raw->Loop(); });
  return std::unique_ptr<RequestGuard>(new RequestGuard(std::move(impl)));
}

RequestGuard::~RequestGuard() { Stop(); }

int RequestGuard::port() const { return impl_->port; }

void RequestGuard::Stop() {
  if (!impl_ || !impl_->thread.joinable()) return;
  impl_->stopping = true;
  const char byte = 0;
  (void)!::write(impl_->wake[1], &byte, 1);
  impl_->thread.join();
}

}  // namespace gonio::daemon
