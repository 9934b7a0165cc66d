// What the fuzz targets share: the plan context of the example instrument (two axes, the
// catalogue's specimens, a 512 x 512 image), and a file holding the input for parsers that read
// paths.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <fstream>
#include <string>

#include "acquisition/plan.h"

namespace gonio::fuzz {

inline acquisition::PlanContext Context() {
  acquisition::PlanContext c;
  c.specimens = {{"ground-glass-G1", "glass", 6, 1.51, 0.344},
                 {"antiglare-A1", "glass", 3, 1.51, 0.023}};
  devices::AxisSettings sample{.name = "sample", .slave_id = 1};
  sample.min_deg = -80, sample.max_deg = 80;
  devices::AxisSettings arm{.name = "arm", .slave_id = 2};
  arm.min_deg = 0, arm.max_deg = 360;
  c.axes = {sample, arm};
  c.image_width = c.image_height = 512;
  return c;
}

// The input as a file (one per process, rewritten for each input).
inline std::string AsFile(const std::uint8_t* data, std::size_t size, const char* ext) {
  static const std::string path = "/tmp/gonio_fuzz_" + std::to_string(::getpid()) + ext;
  std::ofstream(path, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

}  // namespace gonio::fuzz
