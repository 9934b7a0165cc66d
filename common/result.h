// Errors as values (docs/design.md): fallible calls return Result<T>, holding either a T or an
// Error with a code and a message that a person can act on. Bugs (violated invariants) abort.
// (std::expected would do; it needs C++23, and the project builds as C++20.)
#pragma once

#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <variant>

namespace gonio {

enum class ErrorCode {
  kInvalidArgument,  // the caller's input is wrong (bad file, bad option, bad data)
  kNotConnected,
  kTimeout,
  kProtocol,
  kBusy,
  kAborted,
  kIo,
  kNumerical,           // a computation could not produce a trustworthy number
  kDeviceFault,         // the device reports a fault (an alarm, a limit, a failed readback)
  kNotFound,            // no such run, job or record
  kFailedPrecondition,  // not now: the state does not allow it (pause when idle, cancel a running
                        // job)
};

inline const char* ToString(ErrorCode c) {
  switch (c) {
    case ErrorCode::kInvalidArgument:
      return "invalid argument";
    case ErrorCode::kNotConnected:
      return "not connected";
    case ErrorCode::kTimeout:
      return "timeout";
    case ErrorCode::kProtocol:
      return "protocol error";
    case ErrorCode::kBusy:
      return "busy";
    case ErrorCode::kAborted:
      return "aborted";
    case ErrorCode::kIo:
      return "I/O error";
    case ErrorCode::kNumerical:
      return "numerical error";
    case ErrorCode::kDeviceFault:
      return "device fault";
    case ErrorCode::kNotFound:
      return "not found";
    case ErrorCode::kFailedPrecondition:
      return "failed precondition";
  }
  return "error";
}

struct Error {
  ErrorCode code = ErrorCode::kInvalidArgument;
  std::string message;

  std::string ToString() const { return std::string(gonio::ToString(code)) + ": " + message; }
};

template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}      // NOLINT: implicit, like std::expected
  Result(Error error) : v_(std::move(error)) {}  // NOLINT

  bool ok() const { return v_.index() == 0; }
  explicit operator bool() const { return ok(); }

  // Precondition: ok(). Calling these on an error is a bug and aborts.
  T& value() & { return std::get<0>(Check()); }
  const T& value() const& { return std::get<0>(Check()); }
  T&& value() && { return std::get<0>(std::move(Check())); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() { return value(); }
  const T& operator*() const { return value(); }

  // Precondition: !ok().
  const Error& error() const {
    if (ok()) Abort("Result::error() called on a value");
    return std::get<1>(v_);
  }

 private:
  [[noreturn]] static void Abort(const char* what) {
    std::fprintf(stderr, "gonio: bug: %s\n", what);
    std::abort();
  }
  std::variant<T, Error>& Check() {
    if (!ok()) Abort(("Result::value() on error: " + std::get<1>(v_).ToString()).c_str());
    return v_;
  }
  const std::variant<T, Error>& Check() const {
    if (!ok()) Abort(("Result::value() on error: " + std::get<1>(v_).ToString()).c_str());
    return v_;
  }

  std::variant<T, Error> v_;
};

// Result of a call that returns nothing but may fail.
using Status = Result<std::monostate>;
inline Status OkStatus() { return std::monostate{}; }

inline Error InvalidArgument(std::string message) {
  return {ErrorCode::kInvalidArgument, std::move(message)};
}

}  // namespace gonio
