// Runs an engine's run to its end the way goniod's controller does (daemon/service/controller.cc):
// a run the engine left paused on a device fault (the camera opened again mid-point, a timeout
// the drivers' own retries did not clear) is resumed and its pending points measured again. For
// tests of what a run measures, not of how the devices recover (the backends' and the daemon's
// tests do that): a loaded CI host (ASan beside fuzz replays) has cost a point a camera reopen.
#pragma once

#include <atomic>
#include <cstdint>
#include <cstdio>

#include "acquisition/engine.h"

namespace gonio::testing {

// Up to `resumes` resumes; an interrupt (kAborted) is not resumed. Each fault is printed.
inline Status RunResuming(acquisition::Engine& engine, std::int64_t run,
                          const acquisition::Plan& plan, const std::atomic<bool>& stop,
                          int resumes = 2) {
  Status s = engine.Run(run, plan, stop);
  for (int k = 0; k < resumes && !s.ok() && s.error().code != ErrorCode::kAborted; ++k) {
    std::printf("resumed after a device fault, as goniod does: %s\n", s.error().message.c_str());
    s = engine.Run(run, plan, stop);
  }
  return s;
}

}  // namespace gonio::testing
