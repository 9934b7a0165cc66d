// Reading TOML files with errors that name the file and line ("plan.toml:12: ..."): every config
// parser of the project (gonio-sim's, the instrument's, plans, schedules) uses this one reader,
// so unknown keys, wrong types and out-of-range values are refused the same way everywhere.
#pragma once

#include <arpa/inet.h>
#include <netinet/in.h>

#include <toml++/toml.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <set>
#include <sstream>
#include <string>
#include <type_traits>

#include "common/result.h"

namespace gonio::config {

// Reads one key of a table into *out when present, checking its type and range.
class Reader {
 public:
  explicit Reader(std::string path) : path_(std::move(path)) {}

  Error Fail(const toml::node* node, const std::string& what) const {
    std::ostringstream s;
    s << path_;
    // Something missing has no line of its own: the message says the whole file was searched.
    if (node != nullptr && node->source().begin.line > 0)
      s << ":" << node->source().begin.line << ": ";
    else
      s << ": (whole file) ";
    s << what;
    return Error{ErrorCode::kInvalidArgument, s.str()};
  }

  // Known keys only: a misspelt key is an error, not a silent default.
  Status Keys(const toml::table& t, const std::string& where, std::set<std::string> known) {
    for (const auto& [k, v] : t) {
      if (!known.count(std::string(k.str()))) {
        return Fail(&v, "unknown key '" + std::string(k.str()) + "' in [" + where + "]");
      }
    }
    return OkStatus();
  }

  Status Number(const toml::table& t, const char* key, double* out, double lo, double hi) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return OkStatus();
    const auto v = n->value<double>();
    if (!v) return Fail(n, std::string("'") + key + "' must be a number");
    if (!(*v >= lo && *v <= hi)) {
      std::ostringstream s;
      s << "'" << key << "' = " << *v << " is outside [" << lo << ", " << hi << "]";
      return Fail(n, s.str());
    }
    *out = *v;
    return OkStatus();
  }

  // The same for a narrower integer field (int, uint16_t, ...): read, range-checked, stored.
  template <typename Int>
  requires(!std::is_same_v<Int, std::int64_t>) Status
      Integer(const toml::table& t, const char* key, Int* out, std::int64_t lo, std::int64_t hi) {
    std::int64_t v = static_cast<std::int64_t>(*out);
    if (Status s = Integer(t, key, &v, lo, hi); !s.ok()) return s;
    *out = static_cast<Int>(v);
    return OkStatus();
  }

  Status Integer(const toml::table& t, const char* key, std::int64_t* out, std::int64_t lo,
                 std::int64_t hi) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return OkStatus();
    const auto v = n->value_exact<std::int64_t>();
    if (!v) return Fail(n, std::string("'") + key + "' must be an integer");
    if (*v < lo || *v > hi) {
      std::ostringstream s;
      s << "'" << key << "' = " << *v << " is outside [" << lo << ", " << hi << "]";
      return Fail(n, s.str());
    }
    *out = *v;
    return OkStatus();
  }

  // A string naming one of `names` into *out: names[i] is the enum's value i. A name not among
  // them fails as String's allowed list does, naming them.
  template <typename E, std::size_t N>
  Status Choice(const toml::table& t, const char* key, E* out,
                const std::array<const char*, N>& names) {
    std::string name = names[static_cast<std::size_t>(*out)];
    if (Status s = String(t, key, &name, std::set<std::string>(names.begin(), names.end()));
        !s.ok())
      return s;
    for (std::size_t i = 0; i < N; ++i)
      if (name == names[i]) *out = static_cast<E>(i);
    return OkStatus();
  }

  Status String(const toml::table& t, const char* key, std::string* out,
                const std::set<std::string>& allowed = {}) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return OkStatus();
    const auto v = n->value<std::string>();
    if (!v) return Fail(n, std::string("'") + key + "' must be a string");
    if (!allowed.empty() && !allowed.count(*v)) {
      std::string list;
      for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
      return Fail(n, std::string("'") + key + "' = \"" + *v + "\" is not one of: " + list);
    }
    *out = *v;
    return OkStatus();
  }

  // A numeric IPv4 address ("192.168.1.20"). Names are refused, not resolved: nothing in the
  // instrument resolves names (libmodbus turns a name into 255.255.255.255, a broadcast), and the
  // broadcast and unspecified addresses are refused too.
  Status Ipv4(const toml::table& t, const char* key, std::string* out) {
    if (Status s = String(t, key, out); !s.ok() || t.get(key) == nullptr) return s;
    in_addr a{};
    const bool numeric = ::inet_pton(AF_INET, out->c_str(), &a) == 1;
    if (!numeric || a.s_addr == INADDR_BROADCAST || a.s_addr == 0)  // 0: 0.0.0.0
      return Fail(t.get(key), std::string("'") + key + "' = \"" + *out +
                                  "\" must be a numeric IPv4 address of the device, such as "
                                  "192.168.1.20" +
                                  (numeric ? " (not a broadcast or 0.0.0.0)"
                                           : " (names are not resolved: a name could be turned "
                                             "into a broadcast address)"));
    return OkStatus();
  }

  Status Bool(const toml::table& t, const char* key, bool* out) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return OkStatus();
    const auto v = n->value_exact<bool>();
    if (!v) return Fail(n, std::string("'") + key + "' must be true or false");
    *out = *v;
    return OkStatus();
  }

 private:
  std::string path_;
};

// Parses a file, turning toml++'s parse error into "path:line: what".
inline Result<toml::table> ParseTomlFile(const std::string& path) {
  try {
    return toml::parse_file(path);
  } catch (const toml::parse_error& e) {
    std::ostringstream s;
    s << path << ":" << e.source().begin.line << ": " << e.description();
    return Error{ErrorCode::kInvalidArgument, s.str()};
  }
}

// Parses text that came from elsewhere (an API request, a stored run): errors read "name:line:".
inline Result<toml::table> ParseTomlText(std::string_view text, const std::string& name) {
  try {
    return toml::parse(text, name);
  } catch (const toml::parse_error& e) {
    std::ostringstream s;
    s << name << ":" << e.source().begin.line << ": " << e.description();
    return Error{ErrorCode::kInvalidArgument, s.str()};
  }
}

}  // namespace gonio::config

// Returns the error of a Status-returning expression from the enclosing function.
#define GONIO_TRY(expr)                                           \
  do {                                                            \
    if (::gonio::Status s_ = (expr); !s_.ok()) return s_.error(); \
  } while (0)
