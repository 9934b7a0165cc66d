// goniod's HTTP API from a local client's side: whatever bytes arrive on a connection (request
// line, headers, body; with or without the right token), the reply is HTTP with a status other
// than 500, and no exception text reaches the client. One controller and API serve every input,
// on a database in /tmp; the devices behind them fail every call (what the handlers do must not
// depend on an instrument), so a queued job suspends on a device fault and stays queued.
//
// The input is the raw request; each "@TOKEN@" in it is replaced by the API's token, so the
// seeds can carry authenticated mutations (fuzz/corpus/http_api_fuzz/).
#include <sys/socket.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>

#include "daemon/api/http_api.h"
#include "daemon/service/controller.h"
#include "fuzz/fuzz_support.h"
#include "tests/support/raw_http.h"

namespace {

using gonio::Error;
using gonio::ErrorCode;
using gonio::Result;
using gonio::Status;

const Error kAway{ErrorCode::kNotConnected, "no instrument behind the fuzzed API"};

class AbsentCamera final : public gonio::devices::Camera {
 public:
  std::string Identity() const override { return "absent"; }
  Status SetExposure(double) override { return kAway; }
  Result<double> Exposure() override { return kAway; }
  Result<cv::Size> ImageSize() override { return kAway; }
  Result<gonio::devices::Frame> Snap() override { return kAway; }
  bool ReportsExposureEnd() const override { return false; }
  Status Expose() override { return kAway; }
  Result<gonio::devices::Frame> Retrieve() override { return kAway; }
  Result<double> TemperatureC() override { return kAway; }
  Status SetShutter(bool) override { return kAway; }
  Status SetCooling(bool, double) override { return kAway; }
  Status CoolAndWait(const gonio::devices::TemperatureWait&) override { return kAway; }
};

class AbsentStages final : public gonio::devices::StageController {
 public:
  explicit AbsentStages(std::vector<gonio::devices::AxisSettings> axes) : axes_(std::move(axes)) {}
  const std::vector<gonio::devices::AxisSettings>& axes() const override { return axes_; }
  Status MoveTo(const std::vector<std::pair<std::string, double>>&) override { return kAway; }
  Status Home(const std::vector<std::string>&) override { return kAway; }
  Status StopAll() override { return kAway; }
  Result<gonio::devices::AxisStatus> ReadStatus(const std::string&) override { return kAway; }
  Status ResetAlarm(const std::string&) override { return kAway; }

 private:
  std::vector<gonio::devices::AxisSettings> axes_;
};

constexpr const char* kToken = "0123456789abcdef0123456789abcdef";

struct Daemon {
  std::string db_path = (std::filesystem::temp_directory_path() /
                         ("gonio_http_fuzz_" + std::to_string(::getpid()) + ".sqlite"))
                            .string();
  AbsentCamera camera;
  AbsentStages stages{gonio::fuzz::Context().axes};
  std::unique_ptr<gonio::acquisition::Storage> store;
  std::unique_ptr<gonio::daemon::Controller> controller;
  std::unique_ptr<gonio::daemon::ApiServer> api;

  Daemon() {
    auto db = gonio::acquisition::Storage::Open(db_path);
    if (!db.ok()) Fail("cannot open the database: " + db.error().message);
    store = std::move(db).value();
    gonio::daemon::ControllerOptions co;
    co.run_start.config_text = "# fuzz";
    controller = std::make_unique<gonio::daemon::Controller>(stages, camera, nullptr, *store,
                                                             gonio::fuzz::Context(), co);
    if (Status s = controller->Start(); !s.ok()) Fail("controller: " + s.error().message);
    auto started = gonio::daemon::ApiServer::Start(
        *controller, {.host = "127.0.0.1", .port = 0, .token = kToken, .db_path = db_path});
    if (!started.ok()) Fail("api: " + started.error().message);
    api = std::move(started).value();
  }
  [[noreturn]] static void Fail(const std::string& why) {
    std::fprintf(stderr, "http_api_fuzz: %s\n", why.c_str());
    std::abort();
  }
};

// The reply to one request on its own connection: the request sent, the sending side shut (the
// server sees the end at once instead of waiting out its read timeout), everything read until
// the server closes, or only the head of an event stream (which stays open).
std::string Exchange(int port, const std::string& request) {
  const int fd = gonio::testing::ConnectLoopback(port);
  if (fd < 0) Daemon::Fail("cannot connect to the API");
  for (std::size_t sent = 0; sent < request.size();) {
    const ssize_t n = ::send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) break;  // the server closed early (a refused request): read what it said
    sent += static_cast<std::size_t>(n);
  }
  ::shutdown(fd, SHUT_WR);
  std::string reply;
  char buf[4096];
  for (ssize_t n; (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) {
    reply.append(buf, static_cast<std::size_t>(n));
    const auto head = reply.find("\r\n\r\n");
    if (head != std::string::npos &&
        reply.substr(0, head).find("text/event-stream") != std::string::npos)
      break;
  }
  ::close(fd);
  return reply;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // One for the process, never destroyed (its threads serve until exit); its files go at exit.
  static Daemon* daemon = [] {
    auto* d = new Daemon;
    static const std::string path = d->db_path;
    std::atexit([] {
      for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(path + ext);
    });
    return d;
  }();
  std::string request(reinterpret_cast<const char*>(data), size);
  for (std::size_t at; (at = request.find("@TOKEN@")) != std::string::npos;)
    request.replace(at, 7, kToken);
  const std::string reply = Exchange(daemon->api->port(), request);
  if (reply.empty()) return 0;  // closed without a word (an empty or cut-off request line)
  if (reply.rfind("HTTP/1.1 ", 0) != 0) Daemon::Fail("not an HTTP reply:\n" + reply.substr(0, 200));
  if (reply.compare(9, 3, "500") == 0) Daemon::Fail("500 for:\n" + request.substr(0, 400));
  // Text of an exception, unless the request itself carried it (a 404 names the path asked for).
  for (const char* leak : {"json.exception", "stoll", "stoi", "what()", "basic_string"})
    if (reply.find(leak) != std::string::npos && request.find(leak) == std::string::npos)
      Daemon::Fail(std::string("exception text '") + leak + "' in the reply:\n" + reply);
  return 0;
}
