#include "daemon/api/http_api.h"

#include <httplib.h>
#include <malloc.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>

#include "daemon/console/console.h"
#include "daemon/schedule/schedule.h"
#include "daemon/service/fit_run.h"
#include "fitting/response.h"
#include "fitting/summary_json.h"

namespace gonio::daemon {
namespace {

using nlohmann::json;

constexpr const char* kJson = "application/json";

int HttpStatus(ErrorCode c) {
  switch (c) {
    case ErrorCode::kInvalidArgument:
      return 400;
    case ErrorCode::kNotFound:
      return 404;
    case ErrorCode::kFailedPrecondition:
      return 409;
    default:
      return 500;
  }
}

const char* CodeName(int status) {
  switch (status) {
    case 400:
      return "bad_request";
    case 401:
      return "unauthorized";
    case 404:
      return "not_found";
    case 409:
      return "conflict";
    case 413:
    case 414:
      return "too_large";
    case 503:
      return "unavailable";
    default:
      return "internal";
  }
}

// Bytes that are not UTF-8 (a stored plan's text, a file name in a message) are replaced, so
// that a reply is always valid JSON and never an exception.
void Reply(httplib::Response& res, int status, const json& body) {
  res.status = status;
  res.set_content(body.dump(-1, ' ', false, json::error_handler_t::replace), kJson);
}

void ReplyError(httplib::Response& res, int status, const std::string& message) {
  Reply(res, status, {{"error", {{"code", CodeName(status)}, {"message", message}}}});
}

void ReplyError(httplib::Response& res, const Error& e) {
  ReplyError(res, HttpStatus(e.code), e.message);
}

json RunJson(const acquisition::RunInfo& r) {
  json o{{"id", r.id},
         {"specimen", r.specimen},
         {"specimen_eta", r.specimen_eta},
         {"status", acquisition::ToString(r.status)},
         {"points_total", r.points_total},
         {"points_done", r.points_done},
         {"points_skipped", r.points_skipped}};
  o["monitor_reference_w"] = r.monitor_reference_w ? json(*r.monitor_reference_w) : json(nullptr);
  // What the run was expected to cost and what its points took.
  o["estimate"] = r.estimate ? json{{"total_s", r.estimate->total_s},
                                    {"exposure_s", r.estimate->exposure_s},
                                    {"basis", r.estimate->basis}}
                             : json(nullptr);
  o["exposed_s"] = r.exposed_s ? json(*r.exposed_s) : json(nullptr);
  return o;
}

json StatusJson(const StatusReport& s) {
  json o{{"state", ToString(s.state)}, {"reason", s.reason}, {"queued", s.queued}};
  o["job"] = s.job ? ToJson(*s.job) : json(nullptr);
  o["progress"] = s.progress ? ToJson(*s.progress) : json(nullptr);
  return o;
}

// The request body as a JSON object, or a 400 already written.
std::optional<json> Body(const httplib::Request& req, httplib::Response& res) {
  json j = json::parse(req.body, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) {
    ReplyError(res, 400, "the body is not a JSON object");
    return std::nullopt;
  }
  return j;
}

// The path's id ({id}: digits only, by the route's pattern; `group` counts the pattern's groups
// from 1), or a 400 naming it when it does not fit in 64 bits.
std::optional<std::int64_t> IdOf(const httplib::Request& req, httplib::Response& res,
                                 const char* what, int group = 1) {
  const std::string text = req.matches[group].str();
  std::int64_t id = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), id);
  if (ec != std::errc() || end != text.data() + text.size()) {
    ReplyError(res, 400,
               std::string("the ") + what + " id '" + text.substr(0, 32) +
                   "' is not a number of at most 18 digits");
    return std::nullopt;
  }
  return id;
}

// An optional body field of one JSON type, or a 400 naming the field and the type it needs.
std::optional<std::string> StringField(const json& body, const char* name, std::string fallback,
                                       httplib::Response& res) {
  if (!body.contains(name)) return fallback;
  if (!body[name].is_string()) {
    ReplyError(res, 400, std::string("\"") + name + "\" must be a string");
    return std::nullopt;
  }
  return body[name].get<std::string>();
}
std::optional<bool> BoolField(const json& body, const char* name, bool fallback,
                              httplib::Response& res) {
  if (!body.contains(name)) return fallback;
  if (!body[name].is_boolean()) {
    ReplyError(res, 400, std::string("\"") + name + "\" must be true or false");
    return std::nullopt;
  }
  return body[name].get<bool>();
}
std::optional<int> IntField(const json& body, const char* name, int fallback, int lo, int hi,
                            httplib::Response& res) {
  if (!body.contains(name)) return fallback;
  const json& v = body[name];
  if (!v.is_number_integer() || v.get<std::int64_t>() < lo || v.get<std::int64_t>() > hi) {
    ReplyError(res, 400,
               std::string("\"") + name + "\" must be an integer " + std::to_string(lo) + ".." +
                   std::to_string(hi));
    return std::nullopt;
  }
  return static_cast<int>(v.get<std::int64_t>());
}

json FrameJson(const FrameView& f) {
  json o{{"seq", f.seq},
         {"source", f.source},
         {"exposure_s", f.exposure_s},
         {"at", f.at},
         {"frame_width", f.frame_width},
         {"frame_height", f.frame_height},
         {"scale", f.scale},
         {"width", f.width},
         {"height", f.height},
         {"saturated_pixels", f.saturated_pixels},
         {"saturated_mark", kSaturatedMark},
         {"min", f.min},
         {"max", f.max}};
  o["run"] = f.run ? json(*f.run) : json(nullptr);
  o["point"] = f.point ? json(*f.point) : json(nullptr);
  o["rectangle"] = f.rectangle ? json{{"x", f.rectangle->x},
                                      {"y", f.rectangle->y},
                                      {"width", f.rectangle->width},
                                      {"height", f.rectangle->height}}
                               : json(nullptr);
  return o;
}

// A query parameter that must be an integer lo..hi, or a 400 naming it.
std::optional<int> IntParam(const httplib::Request& req, const char* name, int lo, int hi,
                            httplib::Response& res) {
  const std::string text = req.get_param_value(name);
  int v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size() || v < lo || v > hi) {
    ReplyError(res, 400,
               std::string("the query needs ") + name + " = an integer " + std::to_string(lo) +
                   ".." + std::to_string(hi) +
                   (text.empty() ? "" : ", not '" + text.substr(0, 32) + "'"));
    return std::nullopt;
  }
  return v;
}

}  // namespace

void ReturnLargeBlocksToTheSystem() { ::mallopt(M_MMAP_THRESHOLD, 1 << 20); }

std::string NewToken() {
  std::random_device rd;  // the kernel's random source
  std::ostringstream s;
  for (int i = 0; i < 4; ++i) {
    char b[9];
    std::snprintf(b, sizeof b, "%08x", static_cast<unsigned>(rd()));
    s << b;
  }
  return s.str();
}

Result<std::string> LoadOrCreateToken(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    const std::string token = NewToken();
    const mode_t old = ::umask(027);  // group may read (the operators), others nothing
    {
      std::ofstream out(path);
      out << token << "\n";
      if (!out) {
        ::umask(old);
        return Error{ErrorCode::kIo, path + ": cannot write the token file"};
      }
    }
    ::umask(old);
    ::chmod(path.c_str(), 0640);
    return token;
  }
  std::ifstream in(path);
  std::string token;
  if (!(in >> token) || token.size() < 16)
    return InvalidArgument(path + ":1: the token file holds no token of 16 or more characters");
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 && (st.st_mode & S_IROTH) != 0)
    return InvalidArgument(path + ": the token file is readable by everyone; chmod o-r it");
  return token;
}

Result<std::unique_ptr<ApiServer>> ApiServer::Start(Controller& controller, const ApiOptions& o) {
  if (o.token.empty()) return InvalidArgument("the API needs a token for mutating calls");
  std::unique_ptr<ApiServer> s(new ApiServer);
  s->controller_ = &controller;
  s->o_ = o;
  auto reader = acquisition::Storage::Open(o.db_path);
  if (!reader.ok()) return reader.error();
  s->reader_ = std::move(*reader);
  if (!o.plans_dir.empty()) {
    auto plans = PlanCatalogue::Open(o.plans_dir);
    if (!plans.ok()) return plans.error();
    s->plans_ = std::move(*plans);
  }
  s->server_ = std::make_unique<httplib::Server>();
  // Event streams hold a thread each for as long as they are open: the pool has room for every
  // stream the API admits and kRequestThreads more, so requests are never queued behind streams.
  const int threads = o.max_stream_clients + kRequestThreads;
  s->server_->new_task_queue = [threads] {
    return new httplib::ThreadPool(static_cast<std::size_t>(threads));
  };
  // Bounds on what a request may cost: one request per connection (a body refused before it is
  // read - 401 - is dropped with the connection, never parsed as a next request), and bodies of
  // at most max_body_bytes (413). The request's head, its time and the connections are bounded
  // in front of cpp-httplib, which cannot bound its line reader (request_guard.h): it serves a
  // Unix socket in a directory only goniod's user may enter, and the guard the TCP port.
  s->server_->set_keep_alive_max_count(1);
  s->server_->set_payload_max_length(o.max_body_bytes);
  s->server_->set_read_timeout(5, 0);
  s->server_->set_address_family(AF_UNIX);
  s->Routes();
  char dir[] = "/tmp/goniod-api-XXXXXX";  // mode 0700 (mkdtemp)
  if (::mkdtemp(dir) == nullptr)
    return Error{ErrorCode::kIo,
                 std::string("the API's socket directory: ") + std::strerror(errno)};
  s->socket_dir_ = dir;
  const std::string socket_path = s->socket_dir_ + "/api.sock";
  if (!s->server_->bind_to_port(socket_path, 80))
    return Error{ErrorCode::kIo, "cannot serve the API on " + socket_path};
  ApiServer* raw = s.get();
  s->thread_ = std::thread([raw] { raw->server_->listen_after_bind(); });
  // cpp-httplib's stop() before its loop runs is lost, and Stop() would wait for ever.
  for (int k = 0; k < 400 && !s->server_->is_running(); ++k)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  GuardLimits limits = o.limits;
  limits.max_body_bytes = o.max_body_bytes;
  auto guard = RequestGuard::Start(o.host, o.port, socket_path, limits);
  if (!guard.ok()) return guard.error();  // the destructor stops the server
  s->guard_ = std::move(*guard);
  s->port_ = s->guard_->port();
  return s;
}

ApiServer::~ApiServer() { Stop(); }

void ApiServer::Stop() {
  if (guard_) guard_->Stop();
  if (server_) server_->stop();
  if (thread_.joinable()) thread_.join();
  if (!socket_dir_.empty()) {
    std::error_code ec;
    std::filesystem::remove_all(socket_dir_, ec);
    socket_dir_.clear();
  }
}

void ApiServer::Routes() {
  RouteGuards();
  RouteJobs();
  RouteSchedules();
  RouteControl();
  RouteRuns();
  RouteFits();
  RouteEvents();
  RouteCamera();
  RoutePlans();
  RouteConsole();
}

// The token on every mutating call, and errors as JSON.
void ApiServer::RouteGuards() {
  httplib::Server& srv = *server_;
  // Authorisation of mutating calls, before any handler runs.
  srv.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    if (req.method == "GET" || req.method == "HEAD")
      return httplib::Server::HandlerResponse::Unhandled;
    if (req.get_header_value("Authorization") != "Bearer " + o_.token) {
      ReplyError(res, 401,
                 req.has_header("Authorization")
                     ? "the token is wrong (see goniod's --token-file)"
                     : "this call changes the instrument: send 'Authorization: Bearer <token>'");
      return httplib::Server::HandlerResponse::Handled;
    }
    return httplib::Server::HandlerResponse::Unhandled;
  });
  srv.set_error_handler([this](const httplib::Request& req, httplib::Response& res) {
    if (res.status == 404 && res.body.empty())
      ReplyError(res, 404, "no endpoint " + req.method + " " + req.path + " (see docs/api.md)");
    if (res.status == 413 && res.body.empty())
      ReplyError(res, 413,
                 "the body is larger than " + std::to_string(o_.max_body_bytes) + " bytes");
    if (res.status == 414 && res.body.empty())
      ReplyError(res, 414, "the request line is longer than 8192 bytes");
  });
  // Anything a handler did not expect: logged with a number, and the client gets the number,
  // never the exception's text.
  srv.set_exception_handler(
      [](const httplib::Request& req, httplib::Response& res, std::exception_ptr ep) {
        static std::atomic<long> incidents{0};
        const long n = ++incidents;
        std::string what = "unknown exception";
        try {
          std::rethrow_exception(ep);
        } catch (const std::exception& e) {
          what = e.what();
        } catch (...) {
        }
        std::cerr << "goniod: API internal error #" << n << " on " << req.method << " " << req.path
                  << ": " << what << "\n";
        ReplyError(res, 500,
                   "internal error #" + std::to_string(n) + " (goniod's log has the details)");
      });
}

// The status and the job queue: list, one job, submit, cancel, move.
void ApiServer::RouteJobs() {
  httplib::Server& srv = *server_;
  Controller& c = *controller_;
  srv.Get("/api/v1/status", [&c](const httplib::Request&, httplib::Response& res) {
    Reply(res, 200, StatusJson(c.Report()));
  });

  srv.Get("/api/v1/jobs", [&c](const httplib::Request&, httplib::Response& res) {
    json list = json::array();
    for (const Job& j : c.Jobs()) list.push_back(ToJson(j));
    Reply(res, 200, {{"jobs", list}});
  });
  srv.Get(R"(/api/v1/jobs/(\d+))", [&c](const httplib::Request& req, httplib::Response& res) {
    const auto id = IdOf(req, res, "job");
    if (!id) return;
    auto j = c.GetJob(*id);
    if (!j.ok()) return ReplyError(res, j.error());
    Reply(res, 200, ToJson(*j));
  });
  srv.Post("/api/v1/jobs", [&c](const httplib::Request& req, httplib::Response& res) {
    auto body = Body(req, res);
    if (!body) return;
    if (!body->contains("plan") || !(*body)["plan"].is_string())
      return ReplyError(res, 400, "the body needs \"plan\": the plan's TOML text");
    const auto name = StringField(*body, "name", "plan", res);
    if (!name) return;
    const auto repeat = IntField(*body, "repeat", 1, 1, 1000, res);
    if (!repeat) return;
    json jobs = json::array();
    for (int k = 0; k < *repeat; ++k) {
      auto j = c.Submit(*name, (*body)["plan"].get<std::string>());
      if (!j.ok()) return ReplyError(res, j.error());
      jobs.push_back(ToJson(*j));
    }
    Reply(res, 201, *repeat == 1 ? jobs[0] : json{{"jobs", jobs}});
  });
  srv.Delete(R"(/api/v1/jobs/(\d+))", [&c](const httplib::Request& req, httplib::Response& res) {
    const auto id = IdOf(req, res, "job");
    if (!id) return;
    auto j = c.Cancel(*id);
    if (!j.ok()) return ReplyError(res, j.error());
    Reply(res, 200, ToJson(*j));
  });
  srv.Post(R"(/api/v1/jobs/(\d+)/position)",
           [&c](const httplib::Request& req, httplib::Response& res) {
             auto body = Body(req, res);
             if (!body) return;
             const auto id = IdOf(req, res, "job");
             if (!id) return;
             if (!body->contains("position"))
               return ReplyError(res, 400, "the body needs \"position\": an integer (0 = next)");
             const auto position = IntField(*body, "position", 0, 0, 1'000'000, res);
             if (!position) return;
             Status s = c.Move(*id, *position);
             if (!s.ok()) return ReplyError(res, s.error());
             json list = json::array();
             for (const Job& j : c.Jobs()) list.push_back(ToJson(j));
             Reply(res, 200, {{"jobs", list}});
           });
}

// Schedules: validated with their plans, then queued or only described.
void ApiServer::RouteSchedules() {
  httplib::Server& srv = *server_;
  Controller& c = *controller_;
  // A schedule with its plans' texts: validated against the instrument, then queued (or, with
  // "dry_run", only described: what would run and how long it would take).
  srv.Post("/api/v1/schedules", [this, &c](const httplib::Request& req, httplib::Response& res) {
    auto body = Body(req, res);
    if (!body) return;
    if (!body->contains("schedule") || !(*body)["schedule"].is_string())
      return ReplyError(res, 400, "the body needs \"schedule\": the schedule's TOML text");
    std::map<std::string, std::string> plans;
    if (body->contains("plans")) {
      if (!(*body)["plans"].is_object())
        return ReplyError(res, 400, "\"plans\" must map each plan's name to its text");
      for (const auto& [k, v] : (*body)["plans"].items()) {
        if (!v.is_string())
          return ReplyError(res, 400, "plan '" + k + "': the text must be a string");
        plans[k] = v.get<std::string>();
      }
    }
    const auto name = StringField(*body, "name", "schedule", res);
    if (!name) return;
    const auto dry_run = BoolField(*body, "dry_run", false, res);
    if (!dry_run) return;
    // Estimates price each point at what the newest finished run of the specimen needed, else
    // at the specimen's expected lobe through the bench's throughput.
    EstimateBasis basis;
    basis.history = [this](const std::string& specimen) {
      auto h = reader_->LatestExposures(specimen);
      return h.ok() ? *h : std::nullopt;
    };
    if (auto t = reader_->LatestThroughput(); t.ok()) basis.throughput = *t;
    if (!basis.throughput) basis.throughput = c.configured_throughput();
    basis.linear_limit_adu = c.engine_options().linear_limit_adu;
    basis.max_ranging_tries = c.engine_options().max_ranging_tries;
    auto schedule =
        ParseSchedule((*body)["schedule"].get<std::string>(), *name, plans, c.context(), basis);
    if (!schedule.ok()) return ReplyError(res, schedule.error());
    if (*dry_run) {
      json steps = json::array();
      for (const ScheduleEntry& e : schedule->jobs) {
        json step{{"plan", e.plan_name},
                  {"line", e.line},
                  {"repeat", e.repeat},
                  {"points", e.points},
                  {"skipped", e.skipped},
                  {"estimate_s", e.estimate_s},
                  {"estimate_priced", e.estimate_priced},
                  {"estimate_basis", e.estimate_basis}};
        step["start_at_unix"] = e.start_at_unix ? json(*e.start_at_unix) : json(nullptr);
        step["cooler_setpoint_c"] = e.cooler ? json(e.cooler->setpoint_c) : json(nullptr);
        step["fit"] = e.fit;
        steps.push_back(step);
      }
      return Reply(
          res, 200,
          {{"dry_run", true}, {"jobs", steps}, {"estimate_s", schedule->EstimateSeconds()}});
    }
    auto jobs = c.Submit(*schedule);
    if (!jobs.ok()) return ReplyError(res, jobs.error());
    json list = json::array();
    for (const Job& j : *jobs) list.push_back(ToJson(j));
    Reply(res, 201, {{"jobs", list}, {"estimate_s", schedule->EstimateSeconds()}});
  });
}

// Run control: pause, resume, abort.
void ApiServer::RouteControl() {
  httplib::Server& srv = *server_;
  Controller& c = *controller_;
  auto control = [&c](Status (Controller::*op)()) {
    return [&c, op](const httplib::Request&, httplib::Response& res) {
      Status s = (c.*op)();
      if (!s.ok()) return ReplyError(res, s.error());
      Reply(res, 200, StatusJson(c.Report()));
    };
  };
  srv.Post("/api/v1/pause", control(&Controller::Pause));
  srv.Post("/api/v1/resume", control(&Controller::Resume));
  srv.Post("/api/v1/abort", control(&Controller::Abort));
}

// Stored runs: the list, one run with its measurements and events, its CSV.
void ApiServer::RouteRuns() {
  httplib::Server& srv = *server_;
  srv.Get("/api/v1/runs", [this](const httplib::Request&, httplib::Response& res) {
    auto runs = reader_->ListRuns();
    if (!runs.ok()) return ReplyError(res, runs.error());
    json list = json::array();
    for (const auto& r : *runs) list.push_back(RunJson(r));
    Reply(res, 200, {{"runs", list}});
  });
  // The bench's throughput and noise measured on the newest finished run with a fit: what the
  // instrument config's [throughput] holds, so that a new database prices its first runs.
  srv.Get("/api/v1/throughput", [this](const httplib::Request&, httplib::Response& res) {
    auto t = reader_->LatestThroughput();
    if (!t.ok()) return ReplyError(res, t.error());
    if (!*t)
      return ReplyError(res, 404,
                        "no finished run with a fit in this database: the bench's throughput is "
                        "measured on one (run a plan with a fit first)");
    json j{{"run", (*t)->run},
           {"scale", (*t)->scale},
           {"floor", (*t)->floor},
           {"adu_per_value", (*t)->adu_per_value},
           {"dark_adu", (*t)->dark_adu}};
    if (const auto& n = (*t)->noise)
      j["noise"] = {{"shot", n->shot}, {"read", n->read}, {"lamp", n->lamp}, {"dark", n->dark}};
    Reply(res, 200, j);
  });
  srv.Get(R"(/api/v1/runs/(\d+))", [this](const httplib::Request& req, httplib::Response& res) {
    const auto id = IdOf(req, res, "run");
    if (!id) return;
    auto info = reader_->GetRun(*id);
    if (!info.ok()) return ReplyError(res, 404, info.error().message);
    auto rows = reader_->Measurements(info->id);
    if (!rows.ok()) return ReplyError(res, rows.error());
    json o = RunJson(*info);
    o["plan"] = info->plan_text;
    json ms = json::array();
    for (const auto& r : *rows)
      ms.push_back(
          {{"index", r.point.index},
           {"theta_l_deg", r.point.theta_l_deg},
           {"theta_v_deg", r.point.theta_v_deg},
           {"phi_deg", r.point.phi_deg},
           {"side", ToString(r.point.reflection ? acquisition::Side::kReflection
                                                : acquisition::Side::kTransmission)},
           {"value", r.m.value},
           {"sigma", r.m.sigma},
           {"exposure_s", r.m.exposure_s},
           {"frames", r.m.frames},
           {"temperature_c", r.m.temperature_c},
           {"monitor_w", r.m.monitor_w ? json(*r.m.monitor_w) : json(nullptr)},
           {"background", r.m.background ? json(*r.m.background) : json(nullptr)},
           {"sigma_background", r.m.background ? json(r.m.sigma_background) : json(nullptr)},
           {"flags", r.m.flags}});
    o["measurements"] = ms;
    auto events = reader_->Events(info->id);
    if (!events.ok()) return ReplyError(res, events.error());
    json ev = json::array();
    for (const auto& e : *events)
      ev.push_back({{"kind", e.kind}, {"detail", e.detail}, {"at", e.at}});
    o["events"] = ev;
    Reply(res, 200, o);
  });
  srv.Get(R"(/api/v1/runs/(\d+)/csv)", [this](const httplib::Request& req, httplib::Response& res) {
    const auto id = IdOf(req, res, "run");
    if (!id) return;
    if (auto info = reader_->GetRun(*id); !info.ok())
      return ReplyError(res, 404, info.error().message);
    std::ostringstream text;
    Status s = reader_->ExportCsv(*id, text);
    if (!s.ok()) return ReplyError(res, s.error());
    res.status = 200;
    res.set_content(text.str(), "text/csv");
  });
}

// Fits of a run, stored with it.
void ApiServer::RouteFits() {
  httplib::Server& srv = *server_;
  srv.Get(R"(/api/v1/runs/(\d+)/fits)",
          [this](const httplib::Request& req, httplib::Response& res) {
            const auto id = IdOf(req, res, "run");
            if (!id) return;
            if (auto info = reader_->GetRun(*id); !info.ok())
              return ReplyError(res, 404, info.error().message);
            auto fits = reader_->FitResults(*id);
            if (!fits.ok()) return ReplyError(res, fits.error());
            json list = json::array();
            for (const auto& f : *fits)
              list.push_back({{"id", f.id},
                              {"model", f.model},
                              {"created_at", f.created_at},
                              {"summary", json::parse(f.summary, nullptr, false)}});
            Reply(res, 200, {{"fits", list}});
          });
  // A stored fit at each of the run's points, for drawing it beside the data (the console).
  srv.Get(R"(/api/v1/runs/(\d+)/fits/(\d+)/prediction)",
          [this](const httplib::Request& req, httplib::Response& res) {
            const auto id = IdOf(req, res, "run");
            if (!id) return;
            const auto fit_id = IdOf(req, res, "fit", 2);
            if (!fit_id) return;
            const std::int64_t fit = *fit_id;
            if (auto info = reader_->GetRun(*id); !info.ok())
              return ReplyError(res, 404, info.error().message);
            auto points = PredictRun(*reader_, *id, fit);
            if (!points.ok()) return ReplyError(res, points.error());
            json list = json::array();
            for (const PointPrediction& p : *points)
              list.push_back({{"index", p.index},
                              {"theta_l_deg", p.theta_l_deg},
                              {"theta_v_deg", p.theta_v_deg},
                              {"value", p.value}});
            Reply(res, 200, {{"run", *id}, {"fit", fit}, {"points", list}});
          });
  srv.Post(
      R"(/api/v1/runs/(\d+)/fit)", [this](const httplib::Request& req, httplib::Response& res) {
        auto body = Body(req, res);
        if (!body) return;
        std::vector<std::string> models = {"beckmann", "ggx"};
        if (body->contains("models")) {
          if (!(*body)["models"].is_array())
            return ReplyError(res, 400, "\"models\" must be a list of model names");
          models.clear();
          for (const json& m : (*body)["models"]) {
            if (!m.is_string()) return ReplyError(res, 400, "\"models\" must hold strings");
            models.push_back(m.get<std::string>());
          }
        }
        const auto id = IdOf(req, res, "run");
        if (!id) return;
        auto fits = FitRun(*reader_, *id, models, FitProgressEvents(controller_->events(), *id));
        if (!fits.ok()) return ReplyError(res, fits.error());
        json list = json::array();
        for (const RunFit& f : *fits) {
          json j = fitting::ToJson(f.summary);
          j["id"] = f.stored_id;
          j["samples"] = f.samples;
          list.push_back(j);
        }
        Reply(res, 200, {{"fits", list}});
      });
}

// The live event stream.
void ApiServer::RouteEvents() {
  httplib::Server& srv = *server_;
  Controller& c = *controller_;
  // Server-sent events: every event after ?after=N (default: only new ones), as
  // "id: N\nevent: type\ndata: {json}\n\n", with a comment line every 15 s to keep it open.
  srv.Get("/api/v1/events", [this, &c](const httplib::Request& req, httplib::Response& res) {
    std::int64_t after = c.events().Last();
    if (req.has_param("after")) {
      const std::string text = req.get_param_value("after");
      const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), after);
      if (ec != std::errc() || end != text.data() + text.size())
        return ReplyError(res, 400, "?after= must be an event number");
    }
    // A bounded number of streams, each holding a thread (ApiOptions::max_stream_clients).
    if (streams_.fetch_add(1) >= o_.max_stream_clients) {
      streams_.fetch_sub(1);
      res.set_header("Retry-After", "5");
      return ReplyError(res, 503,
                        "already " + std::to_string(o_.max_stream_clients) +
                            " event-stream clients (goniod's limit); close one or poll "
                            "/api/v1/status");
    }
    res.set_header("Cache-Control", "no-cache");
    res.set_chunked_content_provider(
        "text/event-stream",
        [&c, after, idle = 0](std::size_t, httplib::DataSink& sink) mutable {
          if (c.events().closed()) {
            sink.done();
            return true;
          }
          // Short waits: a daemon stopping is never held up by a quiet stream for long.
          auto evs = c.events().After(after, std::chrono::milliseconds(500));
          if (evs.empty()) return ++idle % 30 != 0 || sink.write(": keep-alive\n\n", 14);
          idle = 0;
          std::string out;
          for (const Event& e : evs) {
            out += "id: " + std::to_string(e.seq) + "\nevent: " + e.type +
                   "\ndata: " + e.data.dump() + "\n\n";
            after = e.seq;
          }
          return sink.write(out.data(), out.size());
        },
        [this](bool) { streams_.fetch_sub(1); });
  });
}

// The camera as the console's live view sees it (docs/api.md): the latest frame, downscaled, as
// JSON (what it is) and as raw pixels (little-endian uint16, row-major); a snap between runs; and
// what a rectangle on the frames would take in, from the bench's geometry.
void ApiServer::RouteCamera() {
  httplib::Server& srv = *server_;
  Controller& c = *controller_;
  static constexpr const char* kNoFrame =
      "no frame yet: frames show once a run measures a point, or after a snap (POST "
      "/api/v1/camera/snap)";
  srv.Get("/api/v1/frame", [&c](const httplib::Request&, httplib::Response& res) {
    const auto f = c.frames().Get();
    if (!f) return ReplyError(res, 404, kNoFrame);
    Reply(res, 200, FrameJson(*f));
  });
  srv.Get("/api/v1/frame/pixels", [&c](const httplib::Request&, httplib::Response& res) {
    const auto f = c.frames().Get();
    if (!f) return ReplyError(res, 404, kNoFrame);
    std::string body(f->pixels.size() * 2, '\0');
    for (std::size_t i = 0; i < f->pixels.size(); ++i) {
      body[2 * i] = static_cast<char>(f->pixels[i] & 0xff);
      body[2 * i + 1] = static_cast<char>(f->pixels[i] >> 8);
    }
    res.status = 200;
    res.set_header("X-Frame-Seq", std::to_string(f->seq));
    res.set_header("X-Frame-Width", std::to_string(f->width));
    res.set_header("X-Frame-Height", std::to_string(f->height));
    res.set_header("Cache-Control", "no-store");
    res.set_content(std::move(body), "application/octet-stream");
  });
  srv.Post("/api/v1/camera/snap", [&c](const httplib::Request& req, httplib::Response& res) {
    const auto body = Body(req, res);
    if (!body) return;
    if (!body->contains("exposure_s") || !(*body)["exposure_s"].is_number())
      return ReplyError(res, 400, "the body needs \"exposure_s\": the exposure in seconds");
    auto f = c.Snap((*body)["exposure_s"].get<double>());
    if (!f.ok()) {
      const ErrorCode code = f.error().code;
      // The camera's own failures (no frame, a link that dropped) are the device's, not goniod's.
      if (code == ErrorCode::kTimeout || code == ErrorCode::kDeviceFault ||
          code == ErrorCode::kNotConnected || code == ErrorCode::kAborted)
        return ReplyError(res, 503, "the camera: " + f.error().message);
      return ReplyError(res, f.error());
    }
    Reply(res, 200, FrameJson(**f));
  });
  srv.Get("/api/v1/rectangle", [&c](const httplib::Request& req, httplib::Response& res) {
    const auto& setup = c.context().response;
    if (!setup)
      return ReplyError(res, 409,
                        "the instrument config has no [bench]: a rectangle's size in mm and its "
                        "spread of directions are unknown");
    constexpr int kMax = 1 << 16;
    const auto x = IntParam(req, "x", 0, kMax, res);
    if (!x) return;
    const auto y = IntParam(req, "y", 0, kMax, res);
    if (!y) return;
    const auto w = IntParam(req, "width", 1, kMax, res);
    if (!w) return;
    const auto h = IntParam(req, "height", 1, kMax, res);
    if (!h) return;
    fitting::ResponseSetup s = *setup;
    s.rectangle.x = *x;
    s.rectangle.y = *y;
    s.rectangle.width = *w;
    s.rectangle.height = *h;
    if (req.has_param("specimen")) {
      const std::string name = req.get_param_value("specimen");
      const auto& specimens = c.context().specimens;
      const auto it = std::find_if(specimens.begin(), specimens.end(),
                                   [&](const auto& sp) { return sp.name == name; });
      if (it == specimens.end())
        return ReplyError(res, 400, "no specimen '" + name.substr(0, 64) + "' in the catalogue");
      s.thickness_mm = it->thickness_mm;
    }
    auto cover = fitting::CoverageOf(s);
    if (!cover.ok()) return ReplyError(res, 400, cover.error().message);
    Reply(res, 200,
          json{{"x", *x},
               {"y", *y},
               {"width", *w},
               {"height", *h},
               {"thickness_mm", s.thickness_mm},
               {"width_mm", cover->width_mm},
               {"height_mm", cover->height_mm},
               {"view_spread_deg", {{"rms", cover->view_rms_deg}, {"max", cover->view_max_deg}}},
               {"light_spread_deg", {{"rms", cover->light_rms_deg}, {"max", cover->light_max_deg}}},
               {"rays", cover->rays}});
  });
}

// The instrument's plans (goniod --plans DIR), for submitting without a file at hand.
void ApiServer::RoutePlans() {
  httplib::Server& srv = *server_;
  srv.Get("/api/v1/plans", [this](const httplib::Request&, httplib::Response& res) {
    if (!plans_) return Reply(res, 200, {{"plans", json::array()}, {"configured", false}});
    std::size_t left_out = 0;
    auto list = plans_->List(controller_->context(), &left_out);
    if (!list.ok()) return ReplyError(res, list.error());
    json out = json::array();
    for (const CataloguePlan& p : *list)
      out.push_back({{"name", p.name},
                     {"description", p.description},
                     {"valid", p.valid},
                     {"error", p.error}});
    Reply(res, 200, {{"plans", out}, {"configured", true}, {"left_out", left_out}});
  });
  srv.Get(R"(/api/v1/plans/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    if (!plans_) return ReplyError(res, 404, "goniod was started without --plans: no plans here");
    auto text = plans_->Read(req.matches[1].str());
    if (!text.ok()) return ReplyError(res, text.error());
    Reply(res, 200, {{"name", req.matches[1].str()}, {"text", *text}});
  });
}

// The operator's console: its page and the files it loads, built into goniod. The page may load
// only this origin's scripts and styles, and frames of no other origin may hold it.
void ApiServer::RouteConsole() {
  httplib::Server& srv = *server_;
  srv.Get("/",
          [](const httplib::Request&, httplib::Response& res) { res.set_redirect("/console/"); });
  srv.Get(
      R"(/console/([A-Za-z0-9_.\-]*))", [](const httplib::Request& req, httplib::Response& res) {
        const ConsoleFile* f = FindConsoleFile(req.matches[1].str());
        if (f == nullptr)
          return ReplyError(res, 404, "the console has no file '" + req.matches[1].str() + "'");
        res.status = 200;
        res.set_header("Content-Security-Policy",
                       "default-src 'self'; img-src 'self' data: blob:; frame-ancestors 'none'");
        res.set_header("X-Content-Type-Options", "nosniff");
        res.set_header("Cache-Control", "no-cache");
        res.set_content(std::string(f->body), std::string(ConsoleContentType(f->name)));
      });
}

}  // namespace gonio::daemon
