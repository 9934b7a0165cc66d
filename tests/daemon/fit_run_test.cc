// Fitting a stored run (daemon/service/fit_run.h) refuses a reflection run: its samples are
// f_r cos theta_l with the view above the surface, which no BTDF model of the fitter describes.
// The run's side survives the database (plan_points.side), so the refusal does not depend on
// the plan text.
#include "daemon/service/fit_run.h"

#include <gtest/gtest.h>

#include <unistd.h>
#include <cmath>
#include <filesystem>

namespace gonio::daemon {
namespace {

TEST(FitRun, AReflectionRunIsRefusedAndNothingIsStored) {
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("gonio_fit_run_" + std::to_string(::getpid()) + ".sqlite"))
                               .string();
  std::filesystem::remove(path);
  {
    auto db = acquisition::Storage::Open(path);
    ASSERT_TRUE(db.ok()) << db.error().message;
    std::vector<acquisition::PlannedPoint> pts;
    for (int k = 0; k < 12; ++k) {
      acquisition::PlannedPoint p;
      p.index = k;
      p.theta_l_deg = 30;
      p.theta_v_deg = 10 + 3 * k;
      p.reflection = true;
      p.stage = StageTargetsForReflection(30, p.theta_v_deg);
      pts.push_back(p);
    }
    auto sp = (*db)->EnsureSpecimen({"G1", "glass", 6, 1.51});
    auto cfg = (*db)->StoreConfig("[camera]\n");
    ASSERT_TRUE(sp.ok() && cfg.ok());
    auto run = (*db)->CreateRun(*sp, *cfg, "side = \"reflection\"", pts);
    ASSERT_TRUE(run.ok()) << run.error().message;
    for (const auto& p : pts) {
      acquisition::Measurement m;
      m.index = p.index;
      m.value = 1 + std::exp(-0.01 * (p.theta_v_deg - 30) * (p.theta_v_deg - 30));
      m.sigma = 0.01;
      m.frames = 4;
      m.exposure_s = 1;
      m.rect_pixels = 100;
      ASSERT_TRUE((*db)->StoreMeasurement(*run, m).ok());
    }
    auto fits = FitRun(**db, *run, {"beckmann"});
    ASSERT_FALSE(fits.ok());
    EXPECT_EQ(fits.error().code, ErrorCode::kFailedPrecondition);
    EXPECT_NE(fits.error().message.find("measured reflection"), std::string::npos)
        << fits.error().message;
    auto stored = (*db)->FitResults(*run);
    ASSERT_TRUE(stored.ok());
    EXPECT_TRUE(stored->empty());
  }
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(path + ext);
}

}  // namespace
}  // namespace gonio::daemon
