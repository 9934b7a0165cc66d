// A database in the temporary folder per test, with a run of planned points and measurements to
// store: what the storage tests (acquisition) and the job store's tests (daemon) start from.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "acquisition/storage.h"
#include "common/bench_angles.h"

namespace gonio::testing {

class StorageFixture : public ::testing::Test {
 protected:
  void SetUp() override {
    path = (std::filesystem::temp_directory_path() /
            ("gonio_storage_" + std::to_string(::getpid()) + "_" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".sqlite"))
               .string();
    std::filesystem::remove(path);
  }
  void TearDown() override {
    for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(path + ext);
  }
  std::int64_t NewRun(acquisition::Storage& s, int n_points, int n_skipped = 0) {
    std::vector<acquisition::PlannedPoint> pts;
    for (int k = 0; k < n_points; ++k) {
      acquisition::PlannedPoint p;
      p.index = k;
      p.theta_l_deg = 30;
      p.theta_v_deg = -20 + k;
      p.stage = StageTargetsFor(30, p.theta_v_deg);
      p.skipped = k < n_skipped;
      p.reason = p.skipped ? "test" : "";
      pts.push_back(p);
    }
    auto sp = s.EnsureSpecimen({"G1", "glass", 6, 1.51, std::nullopt});
    auto cfg = s.StoreConfig("[camera]\n");
    EXPECT_TRUE(sp.ok() && cfg.ok());
    auto run = s.CreateRun(*sp, *cfg, "plan text", pts);
    EXPECT_TRUE(run.ok()) << run.error().message;
    return *run;
  }
  acquisition::Measurement M(int index, double value) {
    acquisition::Measurement m;
    m.index = index;
    m.value = value;
    m.sigma = 0.1;
    m.frames = 4;
    m.exposure_s = 0.5;
    m.rect_pixels = 100;
    return m;
  }
  std::string path;
};

}  // namespace gonio::testing
