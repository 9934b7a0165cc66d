// goniod's front door: every connection to the API's TCP port is read here first, and a request
// reaches cpp-httplib (on a Unix socket in a directory only goniod's user can enter) only once
// its head is whole and within bounds. cpp-httplib 0.11 (Debian 12's) reads a request line or a
// header into a string that grows until a newline arrives and counts neither the headers nor the
// time a slow client takes: a 200 MB request line grew goniod by 252 MB before it was refused.
// Here nothing is kept of a request beyond its bounded head, and the bounds are checked as the
// bytes arrive, before any token is looked at:
//   414  the request line longer than max_request_line
//   431  the head longer than max_head_bytes, or more than max_headers headers
//   413  a declared body (Content-Length) longer than max_body_bytes
//   411  a chunked body (no length declared: it could not be bounded before it is read)
//   408  the head not whole within head_timeout_s, or the body not within request_timeout_s
//   503  max_connections already open (the connection is answered and closed at once)
// Each refusal is a JSON error like the API's ({"error": {"code", "message"}}) and the
// connection's close. A request within bounds is passed on byte for byte, and its response (an
// event stream too) passed back for as long as it lasts. One thread, one poll loop: a thousand
// idle connections cost a few kilobytes each and no request thread. One request per connection:
// the server behind must close each connection after its response (goniod's keep-alive is off),
// which is how the guard knows the response is over.
#pragma once

#include <cstddef>
#include <memory>
#include <string>

#include "common/result.h"

namespace gonio::daemon {

struct GuardLimits {
  std::size_t max_request_line = 8192;
  std::size_t max_head_bytes = 32768;  // request line and headers
  int max_headers = 100;
  std::size_t max_body_bytes = 4u << 20;
  double head_timeout_s = 5;      // from the connection's accept
  double request_timeout_s = 30;  // head and body, from the accept
  int max_connections = 256;      // open at once, in any phase
};

class RequestGuard {
 public:
  // Listens on host:port (0: any free port) and passes bounded requests to the HTTP server on
  // the Unix socket `upstream_path`. Errors: the port cannot be bound (kIo).
  static Result<std::unique_ptr<RequestGuard>> Start(const std::string& host, int port,
                                                     const std::string& upstream_path,
                                                     const GuardLimits& limits);
  ~RequestGuard();  // Stop()
  RequestGuard(const RequestGuard&) = delete;
  RequestGuard& operator=(const RequestGuard&) = delete;

  int port() const;
  // Closes the port and every connection; returns once the loop has ended.
  void Stop();

 private:
  struct Impl;
  explicit RequestGuard(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace gonio::daemon
