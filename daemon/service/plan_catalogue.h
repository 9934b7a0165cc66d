// The instrument's plans (goniod --plans DIR): the plan files a lab keeps beside the instrument,
// offered by the console for submitting without a file dialog. Read from the directory at each
// call (a plan edited there is seen at once); only `*.toml` files directly in it, by name.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "acquisition/plan.h"
#include "common/result.h"

namespace gonio::daemon {

struct CataloguePlan {
  std::string name;         // the file's name, "plan_demo.toml"
  std::string description;  // its first comment line, without "# "
  // Whether it loads against the instrument (specimens, travel, image); else why not, with line.
  bool valid = false;
  std::string error;
};

class PlanCatalogue {
 public:
  static constexpr std::size_t kMaxFiles = 200;      // listed; more are left out (and said)
  static constexpr std::size_t kMaxBytes = 1 << 20;  // a plan larger is refused, named

  // kNotFound when `dir` is not a directory.
  static Result<PlanCatalogue> Open(const std::string& dir);

  // The plans by name; `left_out` (optional) counts the files past kMaxFiles.
  Result<std::vector<CataloguePlan>> List(const acquisition::PlanContext& context,
                                          std::size_t* left_out = nullptr) const;
  // A plan's text. kInvalidArgument for a name that is not a plain `*.toml` file name; kNotFound
  // for one not in the directory.
  Result<std::string> Read(const std::string& name) const;

 private:
  explicit PlanCatalogue(std::string dir) : dir_(std::move(dir)) {}
  std::string dir_;
};

}  // namespace gonio::daemon
