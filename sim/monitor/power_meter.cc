#include "sim/monitor/power_meter.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "sim/monitor/usbtmc_device.h"

namespace gonio::sim {

namespace {

using usbtmc::kStatusFailed;
using usbtmc::kStatusSuccess;

std::string Upper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

// Whether a SCPI header matches a pattern such as "SENSe:AVERage[:COUNt]": each node in its short
// (upper-case part) or long form, bracketed nodes optional, a leading ':' allowed.
bool Matches(std::string header, std::string pattern) {
  if (!header.empty() && header[0] == ':') header.erase(0, 1);
  header = Upper(header);
  // A query matches only a query: compare and strip the trailing '?'.
  const bool query = !header.empty() && header.back() == '?';
  if (query != (pattern.back() == '?')) return false;
  if (query) header.pop_back(), pattern.pop_back();
  struct Node {
    std::string shortf, longf;
    bool optional;
  };
  std::vector<Node> nodes;
  std::size_t i = 0;
  while (i < pattern.size()) {
    bool opt = false;
    if (pattern[i] == '[') opt = true, ++i;
    if (pattern[i] == ':') ++i;
    std::string word;
    while (i < pattern.size() && pattern[i] != ':' && pattern[i] != '[' && pattern[i] != ']')
      word += pattern[i++];
    if (i < pattern.size() && pattern[i] == ']') ++i;
    std::string s;
    for (char c : word)
      if (!std::islower(static_cast<unsigned char>(c))) s += c;
    nodes.push_back({s, Upper(word), opt});
  }
  std::vector<std::string> parts;
  std::size_t start = 0;
  for (std::size_t k = 0; k <= header.size(); ++k)
    if (k == header.size() || header[k] == ':')
      parts.push_back(header.substr(start, k - start)), start = k + 1;
  // Match with optional nodes skipped (small lists: plain recursion).
  auto match = [&](auto&& self, std::size_t n, std::size_t p) -> bool {
    if (n == nodes.size()) return p == parts.size();
    if (p < parts.size() && (parts[p] == nodes[n].shortf || parts[p] == nodes[n].longf) &&
        self(self, n + 1, p + 1))
      return true;
    return nodes[n].optional && self(self, n + 1, p);
  };
  return match(match, 0, 0);
}

}  // namespace

SimulatedPowerMeter::SimulatedPowerMeter(const Clock& clock, const Lamp& lamp,
                                         PowerMeterOptions options, std::uint64_t seed,
                                         FaultPlan* faults)
    : clock_(clock), lamp_(lamp), o_(std::move(options)), faults_(faults), rng_(seed ^ 0x9e37) {}

double SimulatedPowerMeter::wavelength_nm() const {
  std::lock_guard lock(mu_);
  return wavelength_nm_;
}

int SimulatedPowerMeter::averaging() const {
  std::lock_guard lock(mu_);
  return averaging_;
}

void SimulatedPowerMeter::Reset() {
  input_.clear();
  output_.clear();
  in_tag_.reset();
  errors_.clear();
  bulk_out_halted_ = false;
  wavelength_nm_ = 633;
  averaging_ = 1;
}

Status SimulatedPowerMeter::Present(double now) {
  if (needs_reopen_ || now < away_until_)
    return Error{ErrorCode::kNotConnected,
                 "LIBUSB_ERROR_NO_DEVICE: source monitor " + o_.serial + " is not on the bus"};
  return OkStatus();
}

Status SimulatedPowerMeter::ClearHalt(devices::UsbTmcEndpoint endpoint) {
  std::lock_guard lock(mu_);
  if (Status s = Present(clock_.Now()); !s.ok()) return s;
  if (endpoint == devices::UsbTmcEndpoint::kBulkOut) bulk_out_halted_ = false;
  return OkStatus();
}

Status SimulatedPowerMeter::Reopen() {
  std::lock_guard lock(mu_);
  if (clock_.Now() < away_until_)
    return Error{ErrorCode::kNotConnected,
                 "no USBTMC device 1313:8072 with serial " + o_.serial + " found"};
  needs_reopen_ = false;
  Reset();  // a re-enumerated device starts from power-up state
  return OkStatus();
}

Status SimulatedPowerMeter::BulkOut(const std::uint8_t* data, std::size_t n, int) {
  std::lock_guard lock(mu_);
  const double now = clock_.Now();
  if (auto e = MaybeFire(faults_, FaultKind::kMonitorDisconnect, "monitor", now)) {
    away_until_ = now + e->duration_s;
    needs_reopen_ = true;
  }
  if (Status s = Present(now); !s.ok()) return s;
  if (bulk_out_halted_)
    return Error{ErrorCode::kIo,
                 "LIBUSB_ERROR_PIPE: source monitor's bulk-out is halted since INITIATE_CLEAR"};
  // A malformed header halts the endpoint, as a real device's STALL.
  if (!usbtmc::ValidHeader(data, n))
    return Error{ErrorCode::kIo, "LIBUSB_ERROR_PIPE: source monitor stalled on a bad header"};
  const std::uint32_t size = usbtmc::TransferSize(data);
  if (data[0] == usbtmc::kDevDepMsgOut) {
    if (size > n - usbtmc::kHeaderBytes)
      return Error{ErrorCode::kIo, "LIBUSB_ERROR_PIPE: TransferSize beyond the transfer"};
    // A new program message while a response is still unread: IEEE 488.2 section 6.3.2.3's
    // INTERRUPTED - the response is discarded and -410 queued (a client that died mid-query).
    if (input_.empty() && !output_.empty()) {
      output_.clear();
      in_tag_.reset();
      errors_.push_back("-410,\"Query INTERRUPTED\"");
    }
    input_.append(reinterpret_cast<const char*>(data + usbtmc::kHeaderBytes), size);
    if (data[usbtmc::kAttributesAt] &
        usbtmc::kEom) {  // EOM: execute every complete line (';' separates commands too)
      std::string all;
      all.swap(input_);
      std::string cmd;
      for (char c : all) {
        if (c == '\n' || c == ';') {
          if (!cmd.empty()) Execute(cmd, now);
          cmd.clear();
        } else if (c != '\r') {
          cmd += c;
        }
      }
      if (!cmd.empty()) Execute(cmd, now);
    }
    return OkStatus();
  }
  if (data[0] == usbtmc::kRequestDevDepMsgIn) {
    in_tag_ = data[1];
    in_max_ = size;
    return OkStatus();
  }
  return Error{ErrorCode::kIo, "LIBUSB_ERROR_PIPE: unknown MsgID " + std::to_string(data[0])};
}

Result<std::size_t> SimulatedPowerMeter::BulkIn(std::uint8_t* data, std::size_t capacity, int) {
  std::lock_guard lock(mu_);
  if (Status s = Present(clock_.Now()); !s.ok()) return s.error();
  // Nothing requested, or nothing to say: the device NAKs until the host gives up.
  if (!in_tag_ || output_.empty() || capacity < usbtmc::kHeaderBytes + 4)
    return Error{ErrorCode::kTimeout, "LIBUSB_ERROR_TIMEOUT: source monitor sent nothing"};
  const std::size_t room = std::min<std::size_t>(in_max_, capacity - usbtmc::kHeaderBytes - 3);
  const std::size_t size = std::min(output_.size(), room);
  const bool eom = size == output_.size();
  const auto h = usbtmc::DevDepMsgInHeader(*in_tag_, static_cast<std::uint32_t>(size), eom);
  std::copy(h.begin(), h.end(), data);
  std::copy(output_.begin(), output_.begin() + static_cast<std::ptrdiff_t>(size),
            data + usbtmc::kHeaderBytes);
  output_.erase(0, size);
  in_tag_.reset();
  std::size_t total = usbtmc::kHeaderBytes + size;
  while (total % 4) data[total++] = 0;
  return total;
}

Result<std::vector<std::uint8_t>> SimulatedPowerMeter::ClassRequest(std::uint8_t request,
                                                                    std::uint16_t value,
                                                                    std::uint16_t length, int) {
  std::lock_guard lock(mu_);
  if (Status s = Present(clock_.Now()); !s.ok()) return s.error();
  std::vector<std::uint8_t> r;
  switch (request) {
    case usbtmc::kInitiateAbortBulkIn: {
      const bool match = in_tag_ && *in_tag_ == static_cast<std::uint8_t>(value);
      // No transfer in progress with that tag: FAILED, as USBTMC 1.0 section 4.2.1.4 says.
      r = {match || !output_.empty() ? kStatusSuccess : kStatusFailed,
           static_cast<std::uint8_t>(value)};
      in_tag_.reset();
      output_.clear();
      break;
    }
    case usbtmc::kCheckAbortBulkInStatus:
      r = {kStatusSuccess, 0, 0, 0, 0, 0, 0, 0};
      break;
    case usbtmc::kInitiateAbortBulkOut:
      input_.clear();
      r = {kStatusSuccess, static_cast<std::uint8_t>(value)};
      break;
    case usbtmc::kCheckAbortBulkOutStatus:
      r = {kStatusSuccess, 0, 0, 0, 0, 0, 0, 0};
      break;
    case usbtmc::kInitiateClear:
      // USBTMC 1.0 table 32: halt bulk-out, drop what it and bulk-in hold.
      bulk_out_halted_ = true;
      input_.clear();
      output_.clear();
      in_tag_.reset();
      r = {kStatusSuccess};
      break;
    case usbtmc::kCheckClearStatus:
      r = {kStatusSuccess, 0};
      break;
    case usbtmc::kGetCapabilities:
      r.assign(24, 0);
      r[0] = kStatusSuccess;
      r[2] = 0x00, r[3] = 0x01;  // bcdUSBTMC 1.00
      break;
    default:
      return Error{ErrorCode::kIo,
                   "LIBUSB_ERROR_PIPE: unsupported class request " + std::to_string(request)};
  }
  if (r.size() > length) r.resize(length);
  return r;
}

void SimulatedPowerMeter::Execute(const std::string& line, double now) {
  std::string text = line;
  while (!text.empty() && std::isspace(static_cast<unsigned char>(text.front()))) text.erase(0, 1);
  const std::size_t sp = text.find_first_of(" \t");
  const std::string header = text.substr(0, sp);
  const std::string arg = sp == std::string::npos ? "" : text.substr(sp + 1);
  auto number = [&](double lo, double hi, double* out) {
    char* end = nullptr;
    const double v = std::strtod(arg.c_str(), &end);
    if (arg.empty() || end == arg.c_str() || !(v >= lo && v <= hi)) {
      errors_.push_back("-222,\"Data out of range\"");
      return false;
    }
    *out = v;
    return true;
  };
  char buf[64];
  if (Matches(header, "*IDN?")) {
    output_ += "gonio-sim,PM100USB (simulated)," + o_.serial + ",1.0.0\n";
  } else if (Matches(header, "*RST")) {
    wavelength_nm_ = 633;
    averaging_ = 1;
  } else if (Matches(header, "*CLS")) {
    errors_.clear();
  } else if (Matches(header, "MEASure[:SCALar]:POWer?")) {
    const double span = averaging_ * o_.sample_s;
    const double mean = lamp_.MeanRelative(std::max(0.0, now - span), std::max(now, span));
    const double noise = o_.noise_rel / std::sqrt(static_cast<double>(averaging_));
    const double w =
        lamp_.NominalW() * mean * (1 + std::normal_distribution<double>(0, noise)(rng_));
    std::snprintf(buf, sizeof buf, "%.6E\n", w);
    output_ += buf;
  } else if (Matches(header, "SENSe:CORRection:WAVelength")) {
    double v;
    if (number(400, 1100, &v)) wavelength_nm_ = v;
  } else if (Matches(header, "SENSe:CORRection:WAVelength?")) {
    std::snprintf(buf, sizeof buf, "%.1f\n", wavelength_nm_);
    output_ += buf;
  } else if (Matches(header, "SENSe:AVERage[:COUNt]")) {
    double v;
    if (number(1, 10000, &v)) averaging_ = static_cast<int>(std::lround(v));
  } else if (Matches(header, "SENSe:AVERage[:COUNt]?")) {
    output_ += std::to_string(averaging_) + "\n";
  } else if (Matches(header, "SYSTem:ERRor[:NEXT]?")) {
    if (errors_.empty()) {
      output_ += "0,\"No error\"\n";
    } else {
      output_ += errors_.front() + "\n";
      errors_.pop_front();
    }
  } else {
    errors_.push_back("-113,\"Undefined header\"");
  }
}

}  // namespace gonio::sim
