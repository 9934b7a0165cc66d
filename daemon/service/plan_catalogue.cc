#include "daemon/service/plan_catalogue.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>

namespace gonio::daemon {
namespace fs = std::filesystem;
namespace {

bool PlainTomlName(const std::string& name) {
  if (name.size() < 6 || name.size() > 128 || name.compare(name.size() - 5, 5, ".toml") != 0)
    return false;
  if (name[0] == '.') return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
           c == '-' || c == '.';
  });
}

std::string FirstComment(const std::string& text) {
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    const auto at = line.find_first_not_of(" \t");
    if (at == std::string::npos) continue;
    if (line[at] != '#') return "";
    const auto from = line.find_first_not_of("# \t", at);
    return from == std::string::npos ? "" : line.substr(from);
  }
  return "";
}

}  // namespace

Result<PlanCatalogue> PlanCatalogue::Open(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    return Error{ErrorCode::kNotFound, "the plans' directory " + dir + " is not a directory"};
  return PlanCatalogue(dir);
}

Result<std::string> PlanCatalogue::Read(const std::string& name) const {
  if (!PlainTomlName(name))
    return Error{ErrorCode::kInvalidArgument,
                 "a plan's name is a file name ending in .toml (letters, digits, _ - .)"};
  const fs::path path = fs::path(dir_) / name;
  std::error_code ec;
  if (!fs::is_regular_file(path, ec))
    return Error{ErrorCode::kNotFound, "no plan " + name + " among the instrument's plans"};
  const auto size = fs::file_size(path, ec);
  if (ec || size > kMaxBytes)
    return Error{ErrorCode::kInvalidArgument,
                 name + ": larger than " + std::to_string(kMaxBytes) + " bytes"};
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  if (!in.good() && !in.eof()) return Error{ErrorCode::kIo, name + ": cannot be read"};
  return text.str();
}

Result<std::vector<CataloguePlan>> PlanCatalogue::List(const acquisition::PlanContext& context,
                                                       std::size_t* left_out) const {
  std::vector<std::string> names;
  std::error_code ec;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (PlainTomlName(name) && it->is_regular_file(ec)) names.push_back(name);
  }
  if (ec) return Error{ErrorCode::kIo, "the plans' directory cannot be read: " + ec.message()};
  std::sort(names.begin(), names.end());
  if (left_out != nullptr) *left_out = names.size() > kMaxFiles ? names.size() - kMaxFiles : 0;
  if (names.size() > kMaxFiles) names.resize(kMaxFiles);
  std::vector<CataloguePlan> out;
  for (const std::string& name : names) {
    CataloguePlan p;
    p.name = name;
    auto text = Read(name);
    if (!text.ok()) {
      p.error = text.error().message;
    } else {
      p.description = FirstComment(*text);
      auto plan = acquisition::LoadPlanText(*text, name, context);
      p.valid = plan.ok();
      if (!plan.ok()) p.error = plan.error().message;
    }
    out.push_back(std::move(p));
  }
  return out;
}

}  // namespace gonio::daemon
