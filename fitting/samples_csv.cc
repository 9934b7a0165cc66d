#include "fitting/samples_csv.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <map>
#include <memory>
#include <sstream>

namespace gonio::fitting {
namespace {

std::string_view Trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
    s.remove_suffix(1);
  return s;
}

std::vector<std::string_view> SplitCommas(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t start = 0;
  for (std::size_t k = 0; k <= line.size(); ++k)
    if (k == line.size() || line[k] == ',') {
      out.push_back(Trim(line.substr(start, k - start)));
      start = k + 1;
    }
  return out;
}

}  // namespace

Result<std::vector<Sample>> ParseSamplesCsv(std::string_view text, const std::string& name) {
  const char* kRequired[] = {"theta_l_deg", "theta_v_deg", "value", "sigma"};
  const char* kOptional[] = {"phi_l_deg", "phi_v_deg"};
  std::map<std::string, std::size_t> column;
  std::vector<Sample> samples;
  std::size_t n_columns = 0;
  bool have_header = false;
  std::shared_ptr<const ResponseSetup> setup;
  int line_no = 0;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t end = std::min(text.find('\n', pos), text.size());
    const std::string_view line = Trim(text.substr(pos, end - pos));
    pos = end + 1;
    ++line_no;
    auto where = [&] { return name + ":" + std::to_string(line_no) + ": "; };
    // "# response: {...}": the instrument response's setup of an exported run (response.h).
    constexpr std::string_view kResponse = "# response:";
    if (line.substr(0, kResponse.size()) == kResponse) {
      auto parsed = ResponseSetup::FromJson(std::string(line.substr(kResponse.size())));
      if (!parsed.ok()) return InvalidArgument(where() + parsed.error().message);
      setup = std::make_shared<const ResponseSetup>(std::move(parsed).value());
    }
    if (line.empty() || line.front() == '#') {
      if (end == text.size()) break;
      continue;
    }
    const auto fields = SplitCommas(line);
    if (!have_header) {
      for (std::size_t k = 0; k < fields.size(); ++k) column[std::string(fields[k])] = k;
      for (const char* c : kRequired)
        if (!column.count(c))
          return InvalidArgument(where() + "header has no column '" + c +
                                 "' (required: theta_l_deg, theta_v_deg, value, sigma)");
      n_columns = fields.size();
      have_header = true;
      continue;
    }
    if (fields.size() != n_columns) {
      std::ostringstream os;
      os << where() << "has " << fields.size() << " fields, the header has " << n_columns;
      return InvalidArgument(os.str());
    }
    auto number = [&](const char* col, double fallback, double* out) -> Status {
      auto it = column.find(col);
      if (it == column.end()) {
        *out = fallback;
        return OkStatus();
      }
      const std::string_view f = fields[it->second];
      const auto r = std::from_chars(f.data(), f.data() + f.size(), *out);
      if (f.empty() || r.ec != std::errc() || r.ptr != f.data() + f.size())
        return InvalidArgument(where() + "column '" + col + "': '" + std::string(f) +
                               "' is not a number");
      if (!std::isfinite(*out))
        return InvalidArgument(where() + "column '" + col + "' is " + std::string(f) +
                               ": values must be finite");
      return OkStatus();
    };
    double tl, tv, value, sigma, pl, pv;
    for (auto [col, out] : {std::pair{kRequired[0], &tl}, std::pair{kRequired[1], &tv},
                            std::pair{kRequired[2], &value}, std::pair{kRequired[3], &sigma}})
      if (Status s = number(col, 0, out); !s) return s.error();
    if (Status s = number(kOptional[0], 0, &pl); !s) return s.error();
    if (Status s = number(kOptional[1], 0, &pv); !s) return s.error();
    // An export marks each point's side: a reflection row's theta_v counts from +n (the camera on
    // the light side, common/bench_angles.h) and it is fitted with the BRDF.
    bool reflection = false;
    if (auto it = column.find("side"); it != column.end()) {
      const std::string_view side = fields[it->second];
      reflection = side == "reflection";
      if (side != "transmission" && side != "reflection" && !side.empty())
        return InvalidArgument(where() + "column 'side': '" + std::string(side) +
                               "' is not transmission or reflection");
    }
    if (!(std::abs(tl) < 90)) return InvalidArgument(where() + "theta_l_deg must lie in (-90, 90)");
    if (!(std::abs(tv) < 90)) return InvalidArgument(where() + "theta_v_deg must lie in (-90, 90)");
    Sample s = reflection ? SampleFromReflectionAngles(tl, pl, tv, pv, value, sigma)
                          : SampleFromBenchAngles(tl, pl, tv, pv, value, sigma);
    s.line = line_no;
    if (Status st = number("sigma_stat", 0, &s.sigma_stat); !st) return st.error();
    // An export's dark set and its shared part of sigma: empty where the point had none.
    if (auto it = column.find("dark_set"); it != column.end() && !fields[it->second].empty()) {
      const std::string_view f = fields[it->second];
      const auto r = std::from_chars(f.data(), f.data() + f.size(), s.dark_set);
      if (r.ec != std::errc() || r.ptr != f.data() + f.size() || s.dark_set < 0)
        return InvalidArgument(where() + "column 'dark_set': '" + std::string(f) +
                               "' is not a set's id (an integer >= 0)");
      if (Status st = number("sigma_dark", 0, &s.sigma_dark); !st) return st.error();
      if (!(s.sigma_dark >= 0 && s.sigma_dark < sigma))
        return InvalidArgument(where() + "column 'sigma_dark' is " + std::to_string(s.sigma_dark) +
                               ": the dark set's part of sigma must lie in [0, sigma)");
    }
    // An export's background column: set where the point's background was measured (and is
    // already subtracted from value), empty where none was.
    if (auto it = column.find("background"); it != column.end() && !fields[it->second].empty()) {
      double background = 0;
      if (Status st = number("background", 0, &background); !st) return st.error();
      s.background_subtracted = true;
    }
    if (setup) {
      if (!column.count("sample_read_deg") || !column.count("arm_read_deg"))
        return InvalidArgument(where() +
                               "the file has a '# response:' line but no sample_read_deg and "
                               "arm_read_deg columns to place each point");
      StagePosition at;
      if (Status st = number("sample_read_deg", 0, &at.sample_deg); !st) return st.error();
      if (Status st = number("arm_read_deg", 0, &at.arm_deg); !st) return st.error();
      if (Status st = number("azimuth_read_deg", 0, &at.azimuth_deg); !st) return st.error();
      s.response = PointResponse{setup, at};
    }
    samples.push_back(s);
    if (end == text.size()) break;
  }
  if (!have_header) return InvalidArgument(name + ": empty file (no header row)");
  if (samples.empty()) return InvalidArgument(name + ": no samples after the header");
  return samples;
}

Result<std::vector<Sample>> ReadSamplesCsv(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error{ErrorCode::kIo, path + ": cannot open for reading"};
  std::ostringstream buf;
  buf << in.rdbuf();
  return ParseSamplesCsv(buf.str(), path);
}

Status WriteSamplesCsv(const std::string& path, std::span<const Sample> samples) {
  std::ofstream out(path);
  if (!out) return Error{ErrorCode::kIo, path + ": cannot open for writing"};
  out << "theta_l_deg,phi_l_deg,theta_v_deg,phi_v_deg,value,sigma,side\n" << std::setprecision(17);
  for (const Sample& s : samples) {
    const double tl = std::acos(std::clamp(s.light.z, -1.0, 1.0)) / optics::kDeg;
    const double pl = std::atan2(s.light.y, s.light.x) / optics::kDeg;
    // A reflection view is the transmission view at the same angles turned to the air side.
    const optics::Vec3<double> v = IsReflection(s) ? -s.view : s.view;
    const double tv = std::acos(std::clamp(-v.z, -1.0, 1.0)) / optics::kDeg;
    const double pv = std::atan2(v.y, v.x) / optics::kDeg;
    out << tl << ',' << pl << ',' << tv << ',' << pv << ',' << s.value << ',' << s.sigma << ','
        << (IsReflection(s) ? "reflection" : "transmission") << '\n';
  }
  if (!out) return Error{ErrorCode::kIo, path + ": write failed"};
  return OkStatus();
}

}  // namespace gonio::fitting
