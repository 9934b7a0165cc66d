// The API's front door (daemon/api/request_guard.h) with small bounds, in front of an HTTP
// server on a Unix socket as goniod's: the connections over the bound are answered 503 at once,
// a body that trickles is cut at the request's time, a head that never ends gets 408, and what
// is within bounds (a long streamed response too) passes byte for byte.
#include "daemon/api/request_guard.h"

#include <gtest/gtest.h>
#include <httplib.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "tests/support/raw_http.h"

namespace gonio::daemon {
namespace {

class Guarded : public ::testing::Test {
 protected:
  void SetUp() override {
    dir = std::filesystem::temp_directory_path() / ("gonio_guard_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    const std::string sock = (dir / "api.sock").string();
    server.set_address_family(AF_UNIX);
    server.Get("/hello", [](const httplib::Request&, httplib::Response& r) {
      r.set_content("hello", "text/plain");
    });
    server.Post("/echo", [](const httplib::Request& q, httplib::Response& r) {
      r.set_content(q.body, "text/plain");
    });
    // A response of 2 MB in pieces: more than the guard holds in flight at once.
    server.Get("/big", [](const httplib::Request&, httplib::Response& r) {
      r.set_content_provider(2u << 20, "application/octet-stream",
                             [](std::size_t offset, std::size_t length, httplib::DataSink& sink) {
                               std::string piece(std::min<std::size_t>(length, 65536),
                                                 static_cast<char>('a' + offset % 26));
                               sink.write(piece.data(), piece.size());
                               return true;
                             });
    });
    server.set_keep_alive_max_count(1);  // as goniod's: one request per connection
    ASSERT_TRUE(server.bind_to_port(sock, 80));
    thread = std::thread([this] { server.listen_after_bind(); });
    // A stop() before the listening begins is lost (cpp-httplib): wait for it.
    for (int k = 0; k < 200 && !server.is_running(); ++k)
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    GuardLimits l;
    l.max_connections = 4;
    l.head_timeout_s = 0.5;
    l.request_timeout_s = 1.0;
    l.max_body_bytes = 1000;
    auto g = RequestGuard::Start("127.0.0.1", 0, sock, l);
    ASSERT_TRUE(g.ok()) << g.error().message;
    guard = std::move(*g);
  }
  void TearDown() override {
    if (guard) guard->Stop();
    server.stop();
    if (thread.joinable()) thread.join();
    std::filesystem::remove_all(dir);
  }
  std::filesystem::path dir;
  httplib::Server server;
  std::thread thread;
  std::unique_ptr<RequestGuard> guard;
};

TEST_F(Guarded, WhatIsWithinBoundsPassesByteForByte) {
  httplib::Client c("127.0.0.1", guard->port());
  auto hello = c.Get("/hello");
  ASSERT_TRUE(hello);
  EXPECT_EQ(hello->status, 200);
  EXPECT_EQ(hello->body, "hello");
  const std::string body(1000, 'x');  // at the bound exactly
  auto echo = c.Post("/echo", body, "text/plain");
  ASSERT_TRUE(echo);
  EXPECT_EQ(echo->body, body);
  auto big = c.Get("/big");
  ASSERT_TRUE(big);
  ASSERT_EQ(big->body.size(), 2u << 20);
  EXPECT_EQ(big->body[0], 'a');
  EXPECT_EQ(big->body[65536], static_cast<char>('a' + 65536 % 26));
  auto over = c.Post("/echo", std::string(1001, 'x'), "text/plain");
  ASSERT_TRUE(over);
  EXPECT_EQ(over->status, 413);
}

TEST_F(Guarded, ConnectionsOverTheBoundAreAnswered503AtOnceAndIdleOnes408) {
  std::vector<int> idle;
  for (int k = 0; k < 4; ++k) idle.push_back(gonio::testing::ConnectLoopback(guard->port()));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // accepted by the loop
  const std::string busy =
      gonio::testing::RawExchange(guard->port(), "GET /hello HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(busy.rfind("HTTP/1.1 503", 0), 0u) << busy;
  EXPECT_NE(busy.find("4 connections open already"), std::string::npos) << busy;
  // (Not queued until a place was free: that would have been a 200.)
  int timed_out = 0;
  for (int fd : idle) {
    char buf[512];
    std::string reply;
    for (ssize_t n; (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) reply.append(buf, n);
    timed_out += reply.rfind("HTTP/1.1 408", 0) == 0 ? 1 : 0;
    ::close(fd);
  }
  EXPECT_EQ(timed_out, 4);
  // Their places are free again.
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  const std::string again =
      gonio::testing::RawExchange(guard->port(), "GET /hello HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(again.rfind("HTTP/1.1 200", 0), 0u) << again;
}

TEST_F(Guarded, ABodyThatTricklesIsCutAtTheRequestsTime) {
  const int fd = gonio::testing::ConnectLoopback(guard->port());
  ASSERT_GE(fd, 0);
  const std::string head = "POST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n";
  ASSERT_EQ(::send(fd, head.data(), head.size(), 0), static_cast<ssize_t>(head.size()));
  bool closed = false;
  // A byte every 100 ms: the body would be whole after 10 s; the guard cuts it at 1 s.
  for (int k = 0; k < 40 && !closed; ++k) {
    if (::send(fd, "x", 1, MSG_NOSIGNAL) != 1) closed = true;
    char c;
    if (!closed && ::recv(fd, &c, 1, MSG_DONTWAIT) == 0) closed = true;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ::close(fd);
  EXPECT_TRUE(closed) << "40 bytes of 100 in 4 s and still open";
}

TEST_F(Guarded, AnAddressThatIsNotNumericIsRefusedByName) {
  auto g = RequestGuard::Start("localhost", 0, (dir / "api.sock").string(), GuardLimits{});
  ASSERT_FALSE(g.ok());
  EXPECT_NE(g.error().message.find("'localhost' is not a numeric IPv4 address"), std::string::npos)
      << g.error().message;
}

}  // namespace
}  // namespace gonio::daemon
