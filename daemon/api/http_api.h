// goniod's local API: HTTP with JSON (cpp-httplib), bound to 127.0.0.1 unless configured
// otherwise. Reads are open to local clients; every mutating call (POST, DELETE) needs
// "Authorization: Bearer <token>", the token being the content of a file readable only by the
// operator's group. The endpoints, bodies and errors are documented in docs/api.md.
//
// Errors are JSON {"error": {"code": "...", "message": "..."}} with the status:
//   400 bad JSON, a missing field, a plan that fails validation (its message has name:line)
//   401 a mutating call without the right token
//   404 unknown run, job or path
//   409 not now (pause when idle, cancel a running job)
//   408 a request's head or body slower than the guard's bounds
//   411 a chunked body (no Content-Length)
//   413 a body over max_body_bytes
//   414 a request line over 8 KiB; 431 a head over 32 KiB or 100 headers (request_guard.h)
//   500 a storage error, or an internal error (numbered; the text goes to the log only)
//   503 max_stream_clients event streams are already open, or a snap's camera failed, or the
//       guard's connections are all taken
#pragma once

#include <atomic>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "acquisition/storage.h"
#include "common/result.h"
#include "daemon/api/request_guard.h"
#include "daemon/service/controller.h"
#include "daemon/service/plan_catalogue.h"

namespace httplib {
class Server;
}

namespace gonio::daemon {

struct ApiOptions {
  std::string host = "127.0.0.1";
  int port = 8470;              // 0: any free port (tests)
  std::string token;            // required for mutating calls; never empty
  std::string db_path;          // the runs database, opened again read-side for the API's queries
  int max_stream_clients = 16;  // open event streams; more get 503
  std::size_t max_body_bytes = 4u << 20;  // a schedule with its plans fits many times over
  std::string plans_dir{};                // the instrument's plans (GET /api/v1/plans); empty: none
  GuardLimits limits{};  // the request's head, its time, the connections (request_guard.h)
};

class ApiServer {
 public:
  // Binds and starts serving on its own threads; the controller must outlive the server.
  static Result<std::unique_ptr<ApiServer>> Start(Controller& controller, const ApiOptions& o);
  ~ApiServer();  // Stop()
  ApiServer(const ApiServer&) = delete;
  ApiServer& operator=(const ApiServer&) = delete;

  int port() const { return port_; }
  void Stop();

 private:
  ApiServer() = default;
  void Routes();  // registers each group below
  void RouteGuards();
  void RouteJobs();
  void RouteSchedules();
  void RouteControl();
  void RouteRuns();
  void RouteFits();
  void RouteEvents();
  void RouteCamera();
  void RoutePlans();    // the instrument's plans (--plans)   // the latest frame, a snap between
                        // runs, a rectangle's coverage
  void RouteConsole();  // the operator's page (daemon/console/)

  Controller* controller_ = nullptr;
  ApiOptions o_;
  std::unique_ptr<acquisition::Storage> reader_;
  std::optional<PlanCatalogue> plans_;  // the API's own connection (WAL: no blocking)
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
  std::unique_ptr<RequestGuard> guard_;  // the TCP port, in front of server_
  std::string socket_dir_;               // server_'s Unix socket's private directory
  int port_ = 0;
  std::atomic<int> streams_{0};  // open event streams
  static constexpr int kRequestThreads = 8;
};

// Makes glibc give every freed block of 1 MiB or more back to the system (a fixed mmap
// threshold; glibc's own adapts up to 32 MiB and keeps what is below it for reuse): the bodies
// of up to 4 MiB that authenticated requests carry, and the responses built for them, go back
// once answered. Process-wide: call once at start.
void ReturnLargeBlocksToTheSystem();

// A token for a new token file: 32 hex digits from the system's random source.
std::string NewToken();
// Reads the token file, creating it (mode 0640, a new token) when it does not exist.
Result<std::string> LoadOrCreateToken(const std::string& path);

}  // namespace gonio::daemon
