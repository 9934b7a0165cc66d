// The sweep engine (acquisition/engine.h) on the simulated instrument through the real drivers:
// stages over Modbus TCP, the cooled CCD over GigE Vision, the source monitor over USBTMC, the
// clock at x100. It checks the samples against the ground truth the camera sees, the honesty of
// their uncertainties, the auto-ranged dynamic range, and monitor normalisation of lamp drift.
// Holds the CTest resource lock "gvcp".
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include "acquisition/engine.h"
#include "acquisition/exposure.h"
#include "fitting/fitter.h"
#include "fitting/samples_csv.h"
#include "sim/truth/monte_carlo.h"
#include "tests/support/forecast_case.h"
#include "tests/support/run_resuming.h"
#include "tests/support/sim_instrument.h"

namespace gonio::acquisition {
namespace {

class EngineOnSim : public ::testing::Test {
 protected:
  virtual sim::LampOptions LampOpts() {
    return {.drift_per_hour = 0, .wander_amplitude = 0, .flicker_rms = 0};
  }
  // The sample the camera sees: Walter 2007's ground glass by default.
  virtual std::shared_ptr<const sim::GroundTruth> Truth() {
    return sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  }
  virtual std::vector<sim::FaultEvent> Faults() { return {}; }
  virtual double FrameTimeout() { return 5; }
  virtual bool BeamBlock() { return false; }
  void SetUp() override {
    const Status started = inst.Start({.clock_speed = 300,
                                       .gain_db = 12,
                                       .lamp = LampOpts(),
                                       .truth = Truth(),
                                       .faults = Faults(),
                                       .frame_timeout_s = FrameTimeout(),
                                       .beam_block = BeamBlock()});
    ASSERT_TRUE(started.ok()) << started.error().message;
    db_path = (std::filesystem::temp_directory_path() /
               ("gonio_engine_" + std::to_string(::getpid()) + ".sqlite"))
                  .string();
    std::filesystem::remove(db_path);
    auto db = Storage::Open(db_path);
    ASSERT_TRUE(db.ok());
    store = std::move(*db);
  }
  void TearDown() override {
    store.reset();
    for (const char* ext : {"", "-wal", "-shm", ".plan.toml"})
      std::filesystem::remove(db_path + ext);
  }

  // Writes a plan, loads it against the instrument, creates its run.
  std::pair<Plan, std::int64_t> NewRun(const std::string& geometry, const std::string& exposure,
                                       const std::string& more = "") {
    const std::string path = db_path + ".plan.toml";
    std::ofstream(path) << "sample = \"ground-glass-G1\"\n[geometry]\n"
                        << geometry << "\n[exposure]\n"
                        << exposure << "\n[rectangle]\nx = 253\ny = 246\nwidth = 6\nheight = 19\n"
                        << more;
    PlanContext ctx;
    ctx.specimens = {{"ground-glass-G1", "glass", 6, 1.51, std::nullopt}};
    ctx.axes = inst.axes;
    ctx.beam_block = inst.beam_block;
    ctx.image_width = ctx.image_height = 512;
    auto plan = LoadPlan(path, ctx);
    EXPECT_TRUE(plan.ok()) << plan.error().message;
    auto sp = store->EnsureSpecimen(plan->specimen);
    auto cfg = store->StoreConfig("test");
    auto run = store->CreateRun(*sp, *cfg, plan->text, ExpandPoints(*plan, ctx));
    EXPECT_TRUE(run.ok());
    return {*plan, *run};
  }

  // What the camera sees in the rectangle at these stage angles, in ADU per second above dark:
  // the scene's per-pixel rates (ground truth through the lens, stray light included).
  // With `blocked`, what it sees with the beam block in the beam: the stray light alone.
  double Expected(const PlannedPoint& p, bool blocked = false) const {
    const sim::StageAngles a{p.stage.sample_deg, p.stage.arm_deg, 0, blocked};
    const sim::ImageRegion region;  // the camera's default: the whole 512 x 512 sensor
    double sum = 0;
    for (int row = 246; row < 246 + 19; ++row)
      for (int col = 253; col < 253 + 6; ++col) sum += inst.scene->PixelRate(a, region, col, row);
    const double e_per_adu =
        inst.sim_camera->sensor().options().gain_e_per_adu / std::pow(10, inst.gain_db / 20);
    return sum / (6 * 19) / e_per_adu;
  }
  // A stored value's distance from what the camera sees, in its sigmas. The value is per mW at
  // the monitor; the lamp is steady, so the monitor's own reading converts (its noise is in
  // sigma).
  double Z(const MeasurementRow& r) const {
    const double expected = Expected(r.point) / (*r.m.monitor_w / kMonitorUnitW);
    return (r.m.value - expected) / r.m.sigma;
  }

  // A new run of this geometry and exposure, measured to its end by an engine on the simulated
  // instrument with its monitor: the stored rows (RunToEnd).
  std::vector<MeasurementRow> Measure(const std::string& geometry, const std::string& exposure) {
    auto [plan, run] = NewRun(geometry, exposure);
    Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                  EngineOptions{.linear_limit_adu = 65000});
    return RunToEnd(engine, plan, run);
  }

  // Runs the plan to its end: the stored rows, or none (with a test failure) if the run or the
  // read failed.
  std::vector<MeasurementRow> RunToEnd(Engine& engine, const Plan& plan, std::int64_t run) {
    std::atomic<bool> stop{false};
    const Status s = gonio::testing::RunResuming(engine, run, plan, stop);
    EXPECT_TRUE(s.ok()) << s.error().message;
    auto rows = store->Measurements(run);
    EXPECT_TRUE(rows.ok());
    if (!s.ok() || !rows.ok()) return {};
    return *rows;
  }

  gonio::testing::SimInstrument inst;
  std::string db_path;
  std::unique_ptr<Storage> store;
};

TEST_F(EngineOnSim, SweepReproducesTheGroundTruthWithHonestUncertaintiesOverFourDecades) {
  // Walter 2007 Figure 12's incidences, each swept across its own transmission lobe.
  auto [plan, run] = NewRun(
      "incidence_deg = [0, 30, 60, 80]\nview_about = \"refracted\"\n"
      "view_from_deg = -20\nview_to_deg = 20\nview_step_deg = 5",
      "frames = 4\ninitial_s = 0.01\nmax_s = 100\nfloor = 0.004");
  Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(engine, plan, run);
  ASSERT_EQ(rows.size(), 36u);
  double z2 = 0, zsum = 0, lo = 1e300, hi = 0;
  for (const MeasurementRow& r : rows) {
    ASSERT_TRUE(r.m.monitor_w.has_value());
    const double z = Z(r);
    z2 += z * z;
    zsum += z;
    lo = std::min(lo, r.m.value);
    hi = std::max(hi, r.m.value);
    EXPECT_EQ(r.m.flags, 0) << "underexposed at theta_l " << r.point.theta_l_deg << " theta_v "
                            << r.point.theta_v_deg << " (" << r.m.exposure_s << " s)";
    EXPECT_EQ(r.m.rect_saturated, 0) << "saturated at point " << r.point.index;
    EXPECT_LT(std::abs(z), 5) << "theta_l " << r.point.theta_l_deg << " theta_v "
                              << r.point.theta_v_deg << ": " << r.m.value << " +- " << r.m.sigma
                              << " (z " << z << ")";
  }
  const double n = static_cast<double>(rows.size());
  const double rms = std::sqrt(z2 / n);
  // Honest: residuals over sigma have unit spread (sampling error of the rms ~ 0.1 here).
  EXPECT_GT(rms, 0.7);
  EXPECT_LT(rms, 1.4);
  EXPECT_LT(std::abs(zsum / n), 0.5);
  std::printf("%d points, rms(z) %.3f, mean(z) %.3f, range %.3g\n", static_cast<int>(n), rms,
              zsum / n, hi / lo);
  // Auto-ranging covered the peak and the stray-light floor, four decades apart.
  EXPECT_GT(hi / lo, 1e4) << hi << " / " << lo;
  // The CSV export carries the same samples to the fitter.
  ASSERT_TRUE(store->ExportCsv(run, db_path + ".csv").ok());
  std::filesystem::remove(db_path + ".csv");
}

// A camera applies its exposure in steps (the simulated one, as the Aravis fake camera's register,
// in whole microseconds): the value is counts per second of the exposure applied, which the
// engine reads back, not of the one it asked for.
TEST_F(EngineOnSim, TheValueIsPerSecondOfTheExposureTheCameraApplied) {
  const double asked = 0.0123456789;
  auto [plan, run] = NewRun(
      "incidence_deg = [0]\nview_about = \"refracted\"\nview_from_deg = -5\nview_to_deg = 5\n"
      "view_step_deg = 5",
      "frames = 4\ninitial_s = 0.0123456789\nmin_s = 0.0123456789\nmax_s = 0.0123456789\n"
      "floor = 0");
  Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(engine, plan, run);
  ASSERT_EQ(rows.size(), 3u);
  const auto applied = inst.camera->Exposure();
  ASSERT_TRUE(applied.ok());
  ASSERT_GT(std::abs(*applied - asked), 1e-7) << "the camera applied the request exactly";
  for (const MeasurementRow& r : rows) {
    EXPECT_DOUBLE_EQ(r.m.exposure_s, *applied) << "point " << r.point.index;
    EXPECT_LT(std::abs(Z(r)), 5) << "point " << r.point.index << ": " << r.m.value << " +- "
                                 << r.m.sigma;
    // One exposure, one dark set: each point's sigma_dark is that set's error, the same in
    // counts for every point (the value's unit differs by the monitor's reading), and a part of
    // sigma_stat.
    EXPECT_EQ(r.m.dark_id, rows[0].m.dark_id);
    EXPECT_GT(r.m.sigma_dark, 0);
    EXPECT_LT(r.m.sigma_dark, r.m.sigma_stat);
    EXPECT_NEAR(r.m.sigma_dark * *r.m.monitor_w, rows[0].m.sigma_dark * *rows[0].m.monitor_w,
                1e-12 * rows[0].m.sigma_dark * *rows[0].m.monitor_w);
  }
}

// The lamp term is the frames' common-mode scatter beyond their pixels' noise, pooled by exposure.
// With a steady lamp there is none, and the pool must not invent one. Issue #16's antiglare runs
// showed how it did: a sweep's first points, its tails, met an empty pool at their exposure, so
// their own excess (pixel noise) over their small signal became the lamp's relative variance, and
// a tail's lamp term came out 0.4-1 of its statistical one (and a point after them on the flank
// took it up, scaled by its signal). Every point now takes the run's final pool when Run returns,
// one relative term per exposure, each point's excess weighted by its variance (q + c s^2)^2, which
// leaves the faint points' noise out of it.
TEST_F(EngineOnSim, ASteadyLampAddsNoLampTermAtOneExposure) {
  const auto rows = Measure(
      "incidence_deg = [0]\nview_about = \"refracted\"\n"
      "view_from_deg = -30\nview_to_deg = 30\nview_step_deg = 2.5",
      "frames = 4\ninitial_s = 0.05\nmin_s = 0.05\nmax_s = 0.05\nfloor = 0");
  ASSERT_EQ(rows.size(), 25u);
  double lamp2 = 0, stat2 = 0, z2 = 0, share = 0, lo = 1e300, hi = 0;
  const double relative = rows[0].m.sigma_lamp / std::abs(rows[0].m.value);
  for (const MeasurementRow& r : rows) {
    const Measurement& m = r.m;
    ASSERT_NEAR(m.exposure_s, 0.05, 1e-9);
    ASSERT_EQ(m.frames, 4);
    // One pool, its final estimate: the same relative lamp term at every point.
    EXPECT_NEAR(m.sigma_lamp / std::abs(m.value), relative, 1e-9 * relative + 1e-15)
        << "point " << r.point.index;
    EXPECT_NEAR(m.sigma * m.sigma,
                m.sigma_stat * m.sigma_stat + m.sigma_lamp * m.sigma_lamp +
                    m.sigma_monitor * m.sigma_monitor,
                1e-9 * m.sigma * m.sigma);
    lamp2 += m.sigma_lamp * m.sigma_lamp / (m.sigma_stat * m.sigma_stat);
    stat2 += 1;
    share = std::max(share, m.sigma_lamp / m.sigma_stat);
    z2 += Z(r) * Z(r);
    lo = std::min(lo, m.value);
    hi = std::max(hi, m.value);
    if (std::getenv("PULLS"))
      std::printf("%6.1f value %.4g stat %.3g lamp %.3g z %+.2f\n", r.point.theta_v_deg, m.value,
                  m.sigma_stat, m.sigma_lamp, Z(r));
  }
  const double n = static_cast<double>(rows.size());
  std::printf(
      "25 points, %.3g to %.3g: mean lamp/stat variance %.3f, largest lamp/stat %.2f, "
      "rms pull %.3f\n",
      lo, hi, lamp2 / stat2, share, std::sqrt(z2 / n));
  double faint = 1e300;
  for (const MeasurementRow& r : rows) faint = std::min(faint, r.m.sigma_stat);
  ASSERT_GT(hi / faint, 300);  // bright points and ones lost in noise share the exposure's pool
  // Pure noise in the pool: at the peak, where it is largest against stat, the lamp's variance
  // scatters about 0 by ~0.3 of the statistical one (the bright points' 3 degrees of freedom
  // each); a term as large as stat is 3.4 of those sigmas out. Before, the first flank point
  // had 1.29 and the tails up to 0.2.
  EXPECT_LT(share, 1.0);
  // 25 unit-normal pulls: an rms within 0.6-1.45 with 99.8 % probability.
  EXPECT_GT(std::sqrt(z2 / n), 0.6);
  EXPECT_LT(std::sqrt(z2 / n), 1.45);
}

// Issue #16 item 3: the background measured with the beam blocked ahead of the sample. The
// bench here has a beam block (a flag on a third axis); the plan asks for the background. Each
// point's background must be the stray light the scene adds (its rates with the beam blocked,
// computed here from the scene, not from the engine), the stored value the lobe alone, both
// within their sigmas, and sigma its four components. The flag was left in the beam before the
// run (a run killed during a background): the run's first move takes it out, and the run leaves
// it out. A fit of the samples fits no floor.
class EngineWithBeamBlock : public EngineOnSim {
 protected:
  bool BeamBlock() override { return true; }
};

TEST_F(EngineWithBeamBlock, TheBackgroundIsTheStrayLightAndTheValueTheLobeAlone) {
  ASSERT_TRUE(inst.beam_block.has_value());
  ASSERT_TRUE(inst.stages->MoveTo({{"beam_block", inst.beam_block->blocked_deg}}).ok());
  ASSERT_TRUE(inst.simulated->Angles().beam_blocked);
  auto [plan, run] = NewRun(
      "incidence_deg = [0, 45]\nview_about = \"refracted\"\nview_from_deg = -40\n"
      "view_to_deg = 40\nview_step_deg = 10",
      "frames = 4\ninitial_s = 0.01\nmax_s = 20\nfloor = 0.004", "[background]\nmeasure = true\n");
  Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(engine, plan, run);
  ASSERT_EQ(rows.size(), 18u);
  EXPECT_GE(engine.stats().background_frames, 18 * 4);
  EXPECT_FALSE(inst.simulated->Angles().beam_blocked) << "the run left the flag in the beam";
  double z2 = 0, z2_bg = 0, share = 0;
  std::vector<fitting::Sample> samples;
  for (const MeasurementRow& r : rows) {
    const Measurement& m = r.m;
    ASSERT_TRUE(m.background.has_value()) << "point " << r.point.index;
    ASSERT_TRUE(m.monitor_w.has_value());
    EXPECT_NEAR(m.sigma * m.sigma,
                m.sigma_stat * m.sigma_stat + m.sigma_lamp * m.sigma_lamp +
                    m.sigma_monitor * m.sigma_monitor + m.sigma_background * m.sigma_background,
                1e-9 * m.sigma * m.sigma);
    ASSERT_GT(m.sigma_background, 0);
    const double norm = *m.monitor_w / kMonitorUnitW;
    const double stray = Expected(r.point, true) / norm;
    const double lobe = Expected(r.point) / norm - stray;
    const double z_bg = (*m.background - stray) / m.sigma_background;
    const double z = (m.value - lobe) / m.sigma;
    EXPECT_LT(std::abs(z_bg), 5) << "point " << r.point.index << ": background " << *m.background
                                 << " +- " << m.sigma_background << ", the scene's " << stray;
    EXPECT_LT(std::abs(z), 5) << "point " << r.point.index << ": value " << m.value << " +- "
                              << m.sigma << ", the lobe's " << lobe;
    z2 += z * z;
    z2_bg += z_bg * z_bg;
    share = std::max(share, *m.background / (m.value + *m.background));
    auto sample = fitting::SampleFromBenchAngles(r.point.theta_l_deg, 0, r.point.theta_v_deg, 0,
                                                 m.value, m.sigma);
    sample.background_subtracted = true;
    samples.push_back(sample);
  }
  const double rms = std::sqrt(z2 / 18), rms_bg = std::sqrt(z2_bg / 18);
  std::printf(
      "18 points: rms pull %.3f of the value, %.3f of the background; largest stray "
      "share %.2f\n",
      rms, rms_bg, share);
  // 18 unit-normal pulls: an rms within 0.55-1.5 with 99.8 % probability.
  EXPECT_GT(rms, 0.5);
  EXPECT_LT(rms, 1.5);
  EXPECT_GT(rms_bg, 0.5);
  EXPECT_LT(rms_bg, 1.5);
  // The stray light is a real part of what the camera saw in the tails (not zero by accident).
  EXPECT_GT(share, 0.3);
  fitting::FitOptions fo;  // Beckmann, eta 1.51
  fo.floor = fitting::Floor::kAuto;
  auto fit = fitting::Fit(samples, fo);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  EXPECT_FALSE(fit->floor_fitted);
  EXPECT_NE(fit->floor_choice.find("measured"), std::string::npos) << fit->floor_choice;
  std::printf("Beckmann alpha %.5f +- %.5f, chi2/dof %.2f (the point model)\n", fit->width.value,
              fit->width.sigma, fit->reduced_chi2);
}

// The camera and stages as the engine sees them, with a hook on the split frame: Retrieve()
// waits (up to 3 s) until the stages have begun moving to the next point, which holds only if
// the engine moves while the last frame reads out; and the n-th retrieval can be lost.
class OverlapProbe {
 public:
  class Camera final : public devices::Camera {
   public:
    Camera(devices::Camera& inner, OverlapProbe& probe) : inner_(inner), probe_(probe) {}
    std::string Identity() const override { return inner_.Identity(); }
    Status SetExposure(double s) override { return inner_.SetExposure(s); }
    Result<double> Exposure() override { return inner_.Exposure(); }
    Result<cv::Size> ImageSize() override { return inner_.ImageSize(); }
    Result<devices::Frame> Snap() override { return inner_.Snap(); }
    Result<double> TemperatureC() override { return inner_.TemperatureC(); }
    Status SetShutter(bool open) override { return inner_.SetShutter(open); }
    Status SetCooling(bool on, double sp) override { return inner_.SetCooling(on, sp); }
    Status CoolAndWait(const devices::TemperatureWait& w) override { return inner_.CoolAndWait(w); }
    int Reconnections() const override { return inner_.Reconnections(); }
    bool ReportsExposureEnd() const override { return inner_.ReportsExposureEnd(); }
    Status Expose() override {
      std::lock_guard lock(probe_.mu_);
      probe_.moves_since_expose_ = 0;
      return inner_.Expose();
    }
    Result<devices::Frame> Retrieve() override {
      auto f = inner_.Retrieve();
      std::unique_lock lock(probe_.mu_);
      const int n = ++probe_.retrievals_;
      const bool moved = probe_.cv_.wait_for(lock, std::chrono::seconds(3),
                                             [&] { return probe_.moves_since_expose_ > 0; });
      (moved ? probe_.overlapped_ : probe_.not_overlapped_)++;
      if (n == probe_.lose_retrieval_) return Error{ErrorCode::kTimeout, "lost by the test"};
      return f;
    }

   private:
    devices::Camera& inner_;
    OverlapProbe& probe_;
  };
  class Stages final : public devices::StageController {
   public:
    Stages(devices::StageController& inner, OverlapProbe& probe) : inner_(inner), probe_(probe) {}
    const std::vector<devices::AxisSettings>& axes() const override { return inner_.axes(); }
    Status MoveTo(const std::vector<std::pair<std::string, double>>& targets) override {
      {
        std::lock_guard lock(probe_.mu_);
        ++probe_.moves_since_expose_;
      }
      probe_.cv_.notify_all();
      return inner_.MoveTo(targets);
    }
    Status Home(const std::vector<std::string>& names) override { return inner_.Home(names); }
    Status StopAll() override { return inner_.StopAll(); }
    Result<devices::AxisStatus> ReadStatus(const std::string& name) override {
      return inner_.ReadStatus(name);
    }
    Status ResetAlarm(const std::string& name) override { return inner_.ResetAlarm(name); }
    int Reconnections() const override { return inner_.Reconnections(); }

   private:
    devices::StageController& inner_;
    OverlapProbe& probe_;
  };

  int lose_retrieval_ = 0;  // 1-based; 0: none
  int overlapped_ = 0, not_overlapped_ = 0;

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  int moves_since_expose_ = 0, retrievals_ = 0;
};

// With backgrounds, a point's last frame is its last background frame: it reads out while the
// stages move on (the flag out of the beam with them), and one lost there is retaken back at its
// point with the flag in the beam again - a retake that saw the lobe would put the background
// thousands of sigma off the stray light.
TEST_F(EngineWithBeamBlock, ALostBackgroundFrameIsRetakenWithTheBeamBlocked) {
  auto [plan, run] = NewRun(
      "incidence_deg = [0]\nview_about = \"refracted\"\nview_from_deg = -20\nview_to_deg = 20\n"
      "view_step_deg = 10",
      "frames = 3\ninitial_s = 0.01\nmax_s = 20\nfloor = 0.004", "[background]\nmeasure = true\n");
  OverlapProbe probe;
  probe.lose_retrieval_ = 3;
  OverlapProbe::Camera camera(*inst.camera, probe);
  OverlapProbe::Stages stages(*inst.stages, probe);
  Engine engine(stages, camera, inst.meter, *store, EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(engine, plan, run);
  ASSERT_EQ(rows.size(), 5u);
  EXPECT_EQ(engine.stats().retaken_frames, 1);
  EXPECT_EQ(probe.overlapped_, 4);  // the run's last has no move to overlap
  for (const MeasurementRow& r : rows) {
    ASSERT_TRUE(r.m.background.has_value());
    const double norm = *r.m.monitor_w / kMonitorUnitW;
    const double stray = Expected(r.point, true) / norm;
    std::printf("point %d: background %.4g +- %.2g, the scene's %.4g\n", r.point.index,
                *r.m.background, r.m.sigma_background, stray);
    // Within its sigma, and that sigma no larger than the point's own frames' noise (the
    // background's frames have less light): a frame of the lobe among them would also widen the
    // scatter its sigma is made of.
    EXPECT_LT(r.m.sigma_background, 2 * r.m.sigma_stat) << "point " << r.point.index;
    EXPECT_EQ(r.m.sigma_dark, 0) << "the dark cancels in a background-subtracted value";
    EXPECT_LT(std::abs(*r.m.background - stray), 5 * r.m.sigma_background)
        << "point " << r.point.index << ": background " << *r.m.background << " +- "
        << r.m.sigma_background << ", the scene's " << stray;
    EXPECT_LT(std::abs(r.m.value - (Expected(r.point) / norm - stray)), 5 * r.m.sigma)
        << "point " << r.point.index;
  }
  EXPECT_FALSE(inst.simulated->Angles().beam_blocked);
}

// Issue #6's "the camera reads out while the stages move": every point's last frame but the
// run's last is retrieved while the stages move on, and the samples still match the truth at
// their own geometry. A frame lost in that readout is taken again back at its point.
TEST_F(EngineOnSim, LastFramesReadOutWhileTheStagesMoveAndALostOneIsRetakenAtItsPoint) {
  auto [plan, run] = NewRun(
      "incidence_deg = [0, 30]\nview_about = \"refracted\"\n"
      "view_from_deg = -20\nview_to_deg = 20\nview_step_deg = 10",
      "frames = 3\ninitial_s = 0.01\nmax_s = 100\nfloor = 0.004");
  OverlapProbe probe;
  probe.lose_retrieval_ = 4;
  OverlapProbe::Camera camera(*inst.camera, probe);
  OverlapProbe::Stages stages(*inst.stages, probe);
  ASSERT_TRUE(camera.ReportsExposureEnd());
  Engine engine(stages, camera, inst.meter, *store, EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(engine, plan, run);
  // Ten points: nine last frames overlap a move; the run's last has none to overlap (its wait
  // times out, so it is the one "not overlapped"), and the lost one's retake is a plain Snap.
  EXPECT_EQ(engine.stats().overlapped_readouts, 10);
  EXPECT_EQ(probe.overlapped_, 9);
  EXPECT_EQ(probe.not_overlapped_, 1);
  EXPECT_EQ(engine.stats().retaken_frames, 1);
  ASSERT_EQ(rows.size(), 10u);
  for (const MeasurementRow& r : rows) {
    EXPECT_EQ(r.m.frames, 3) << "point " << r.point.index;
    // Read back at its own geometry, and seeing it: a frame taken during or after the move
    // to the next point would be 10 degrees off its lobe, many sigma away.
    EXPECT_NEAR(r.m.arm_read_deg, r.point.stage.arm_deg, 0.01);
    EXPECT_LT(std::abs(Z(r)), 5) << "point " << r.point.index << ": " << r.m.value << " +- "
                                 << r.m.sigma;
  }
  auto events = store->Events(run);
  ASSERT_TRUE(events.ok());
  int retakes = 0;
  for (const RunEvent& e : *events)
    if (e.kind == "retake") {
      ++retakes;
      EXPECT_NE(e.detail.find("point 3:"), std::string::npos) << e.detail;
    }
  EXPECT_EQ(retakes, 1);
}

// A frame that leaves the camera after the driver stopped waiting for it (frame_late: 600
// simulated seconds, 2 s of real time, against a 1 s wait). The driver has triggered again by
// then, and that trigger's exposure waits for the late frame to leave. Paired by order, the late
// frame was taken for the new trigger's, and from then on every frame for the next trigger's:
// each point's ranging frame was the previous point's last, and values were up to 35 % off with
// a σ that did not cover it (stop 26's note, under load). Paired by the camera's timestamp the
// late frame is refused, the run says so, and every point is its own.
class EngineWithALateFrame : public EngineOnSim {
 protected:
  std::vector<sim::FaultEvent> Faults() override {
    sim::FaultEvent late = sim::OnOpportunity(sim::FaultKind::kFrameLate, 9);
    late.duration_s = 600;
    return {late};
  }
  double FrameTimeout() override { return 1.0; }
};

TEST_F(EngineWithALateFrame, IsRefusedAndEveryLaterPointKeepsItsOwnFrames) {
  auto [plan, run] = NewRun(
      "incidence_deg = [0, 30]\nview_about = \"refracted\"\n"
      "view_from_deg = -20\nview_to_deg = 20\nview_step_deg = 10",
      "frames = 3\ninitial_s = 0.01\nmax_s = 100\nfloor = 0.004");
  Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(engine, plan, run);
  ASSERT_EQ(rows.size(), 10u);
  for (const MeasurementRow& r : rows) {
    EXPECT_EQ(r.m.frames, 3) << "point " << r.point.index;
    EXPECT_EQ(r.m.rect_saturated, 0) << "point " << r.point.index;
    EXPECT_LT(std::abs(Z(r)), 5) << "point " << r.point.index << ": " << r.m.value << " +- "
                                 << r.m.sigma;
  }
  EXPECT_GE(inst.camera->StaleFrames(), 1) << "the late frame was never refused";
  auto events = store->Events(run);
  ASSERT_TRUE(events.ok());
  int refused = 0;
  for (const RunEvent& e : *events)
    if (e.kind == "camera" && e.detail.find("refused") != std::string::npos) ++refused;
  EXPECT_GE(refused, 1) << "the run's log does not say a frame was refused";
}

// A reflection plan (the camera on the light side, issue #6's option): the same engine, with the
// arm at theta_l + theta_v, measures the truth's BRDF * cos theta_l (Walter eq. 20) about each
// incidence's specular direction; the export marks the side, and the fitter (BTDFs only) refuses
// it by file:line instead of fitting it as a transmission lobe.
TEST_F(EngineOnSim, AReflectionSweepMeasuresTheBrdfAboutTheSpecularDirection) {
  auto [plan, run] = NewRun(
      "side = \"reflection\"\nincidence_deg = [30, 60]\nview_about = \"specular\"\n"
      "view_from_deg = -20\nview_to_deg = 20\nview_step_deg = 10",
      "frames = 3\ninitial_s = 0.01\nmax_s = 100\nfloor = 0.004");
  Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(engine, plan, run);
  ASSERT_EQ(rows.size(), 10u);
  std::map<double, double> at_30;  // theta_v -> value
  for (const MeasurementRow& r : rows) {
    EXPECT_TRUE(r.point.reflection);
    EXPECT_NEAR(r.m.arm_read_deg, r.point.theta_l_deg + r.point.theta_v_deg, 0.01);
    EXPECT_LT(std::abs(Z(r)), 5) << "theta_l " << r.point.theta_l_deg << " theta_v "
                                 << r.point.theta_v_deg << ": " << r.m.value << " +- " << r.m.sigma;
    if (r.point.theta_l_deg == 30) at_30[r.point.theta_v_deg] = r.m.value;
  }
  // Independently of the scene: 20 degrees short of specular the half vector is 10 degrees off
  // the normal, so eq. 20 gives D(10 deg) / D(0) * cos(30) / cos(10) of the specular value (F and
  // G change by under 2 %, the stray-light floor adds about 1 %).
  const double t10 = std::tan(10 * M_PI / 180), a = 0.344;
  const double ratio = std::exp(-t10 * t10 / (a * a)) / std::pow(std::cos(10 * M_PI / 180), 4) *
                       std::cos(30 * M_PI / 180) / std::cos(10 * M_PI / 180);
  EXPECT_NEAR(at_30[10] / at_30[30], ratio, 0.05 * ratio);
  const std::string csv = db_path + ".csv";
  ASSERT_TRUE(store->ExportCsv(run, csv).ok());
  auto samples = fitting::ReadSamplesCsv(csv);
  std::filesystem::remove(csv);
  ASSERT_TRUE(samples.ok()) << samples.error().message;
  ASSERT_EQ(samples->size(), rows.size());
  // The export reads back as reflection samples, and the BRDF fit (eq. 20) finds the ground
  // glass's width; the floor is the scene's stray light, about 1 % of the peak.
  EXPECT_TRUE(fitting::IsReflection(samples->front()));
  fitting::FitOptions o;
  o.floor = fitting::Floor::kAuto;
  auto fit = fitting::Fit(*samples, o);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  EXPECT_EQ(fit->status, fitting::FitStatus::kConverged) << fit->message;
  EXPECT_LT(std::abs(fit->width.value - 0.344), 2.5 * fit->width.sigma)
      << fit->width.value << " +- " << fit->width.sigma << ", chi2/dof " << fit->reduced_chi2;
  EXPECT_LT(fit->reduced_chi2, 3) << fit->floor_choice;
  std::cout << "[ info ] reflection fit: alpha " << fit->width.value << " +- " << fit->width.sigma
            << ", chi2/dof " << fit->reduced_chi2 << ", " << fit->floor_choice << "\n";
}

// A lamp drifting 20 %/min: the monitor's normalisation removes it, and without the monitor the
// same geometry measured a minute later reads 20 % higher.
// Issue #18: a daemon's SIGTERM interrupts the point in hand rather than waiting for it. Set
// once the first point is stored, the interrupt ends the run at once: Run returns OK with the run
// paused, the interrupted point is not stored and stays pending (an event says so), the shutter
// is open again, and a resume measures every remaining point exactly once.
TEST_F(EngineOnSim, AnInterruptLeavesThePointInHandPendingAndTheRunResumesWhole) {
  auto [plan, run] = NewRun(
      "incidence_deg = [0]\nview_about = \"refracted\"\nview_from_deg = -4\nview_to_deg = 4\n"
      "view_step_deg = 2",
      "frames = 4\ninitial_s = 0.01");
  std::atomic<bool> stop{false}, interrupt{false};
  {
    Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                  EngineOptions{.linear_limit_adu = 65000});
    engine.InterruptOn(&interrupt);
    const Status s = engine.Run(run, plan, stop, [&](const Progress&) { interrupt = true; });
    ASSERT_TRUE(s.ok()) << s.error().message;
  }
  auto info = store->GetRun(run);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->status, RunStatus::kPaused);
  const auto stored = *store->Measurements(run);
  EXPECT_GE(stored.size(), 1u);
  EXPECT_LT(stored.size(), 5u) << "the interrupt did not stop the run";
  bool said = false;
  const auto events = store->Events(run);
  ASSERT_TRUE(events.ok());
  for (const auto& e : *events)
    said = said || (e.kind == "paused" && e.detail.find("interrupted during point") == 0);
  EXPECT_TRUE(said);
  // The camera is usable again without the flag, and its shutter open: the resumed run's values
  // are not darks.
  Engine again(*inst.stages, *inst.camera, inst.meter, *store,
               EngineOptions{.linear_limit_adu = 65000});
  const auto rows = RunToEnd(again, plan, run);
  ASSERT_EQ(rows.size(), 5u);
  std::set<int> indices;
  for (const auto& r : rows) {
    indices.insert(r.point.index);
    EXPECT_GT(r.m.value, 10 * r.m.sigma) << r.point.index;
  }
  EXPECT_EQ(indices.size(), 5u);
}

class EngineDriftingLamp : public EngineOnSim {
 protected:
  sim::LampOptions LampOpts() override {
    return {.drift_per_hour = 12, .wander_amplitude = 0, .flicker_rms = 0};
  }
};

TEST_F(EngineDriftingLamp, MonitorNormalisationRemovesLampDrift) {
  const std::string geometry =
      "incidence_deg = [30]\nview_about = \"refracted\"\nview_from_deg = -4\nview_to_deg = 4\n"
      "view_step_deg = 4";
  const std::string exposure = "frames = 4\ninitial_s = 0.01";
  auto measure = [&](devices::SourceMonitor* monitor) {
    auto [plan, run] = NewRun(geometry, exposure);
    Engine engine(*inst.stages, *inst.camera, monitor, *store,
                  EngineOptions{.linear_limit_adu = 65000});
    std::atomic<bool> stop{false};
    EXPECT_TRUE(gonio::testing::RunResuming(engine, run, plan, stop).ok());
    return run;
  };
  auto wait_sim = [&](double s) {
    const double t0 = inst.clock->Now();
    while (inst.clock->Now() - t0 < s) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  };
  const auto first = measure(inst.meter);
  wait_sim(60);
  const auto second = measure(inst.meter);
  const auto a = *store->Measurements(first);
  const auto b = *store->Measurements(second);
  ASSERT_EQ(a.size(), 3u);
  ASSERT_EQ(b.size(), 3u);
  for (int k = 0; k < 3; ++k) {
    const double ratio = b[k].m.value / a[k].m.value;
    const double sigma = std::hypot(b[k].m.sigma / b[k].m.value, a[k].m.sigma / a[k].m.value);
    EXPECT_NEAR(ratio, 1.0, 4 * sigma + 0.003) << "point " << k;
  }
  EXPECT_GT(*b[0].m.monitor_w / *a[0].m.monitor_w, 1.15);  // the lamp did drift
  // Without the monitor the drift stays in the data.
  wait_sim(60);
  const auto raw = measure(nullptr);
  const auto c = *store->Measurements(raw);
  // Unnormalised values are counts per second, normalised ones per mW at the monitor: compare
  // the raw value with the first run's times its monitor reading.
  const double first_raw = a[1].m.value * *a[1].m.monitor_w / kMonitorUnitW;
  EXPECT_GT(c[1].m.value / first_raw, 1.3);
}

// Issue #16's budget: with the demo's lamp (drift, slow wander and flicker, config/sim.toml), each
// stored sigma is its components in quadrature (stat, lamp, monitor; the export carries them),
// and two runs of one plan differ point by point about as those sigmas say: the rms of the pulls
// (v1 - v2) / sqrt(s1^2 + s2^2) lies near 1. 27 pairs give it a sampling error of ~0.14;
// eleven runs gave 0.76-1.42, so about 10 % of the scatter is still not in
// the budget (docs/measurement.md). A CI run under load gave one outside 1.5; the bounds are now
// set from the chi-square quantiles (below). PULLS=1 prints every pair.
class EngineOnTheDemoLamp : public EngineOnSim {
 protected:
  sim::LampOptions LampOpts() override { return {}; }  // 1 %/h drift, 0.5 % wander, 0.2 % flicker
};

TEST_F(EngineOnTheDemoLamp, SigmaIsItsComponentsAndRepeatedRunsAgreeWithinIt) {
  const std::string geometry =
      "incidence_deg = [0, 30, 60]\nview_about = \"refracted\"\nview_from_deg = -10\n"
      "view_to_deg = 10\nview_step_deg = 2.5";
  const std::string exposure = "frames = 4\ninitial_s = 0.01\nmax_s = 2\nfloor = 0.004";
  auto measure = [&] {
    auto [plan, run] = NewRun(geometry, exposure);
    Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                  EngineOptions{.linear_limit_adu = 65000});
    return RunToEnd(engine, plan, run);
  };
  const auto a = measure();
  const auto b = measure();
  ASSERT_EQ(a.size(), 27u);
  ASSERT_EQ(b.size(), 27u);
  double z2 = 0, z2_stat = 0, lamp = 0, monitor = 0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    for (const auto* r : {&a[k], &b[k]}) {
      const Measurement& m = r->m;
      EXPECT_NEAR(m.sigma * m.sigma,
                  m.sigma_stat * m.sigma_stat + m.sigma_lamp * m.sigma_lamp +
                      m.sigma_monitor * m.sigma_monitor,
                  1e-9 * m.sigma * m.sigma);
      lamp = std::max(lamp, m.sigma_lamp / m.sigma);
      monitor = std::max(monitor, m.sigma_monitor / m.sigma);
    }
    const double z = (a[k].m.value - b[k].m.value) / std::hypot(a[k].m.sigma, b[k].m.sigma);
    z2 += z * z;
    const double z_stat =
        (a[k].m.value - b[k].m.value) / std::hypot(a[k].m.sigma_stat, b[k].m.sigma_stat);
    z2_stat += z_stat * z_stat;
    if (std::getenv("PULLS"))
      std::printf("%5.1f %6.1f t %.4g/%.4g z %6.2f  stat %.2g lamp %.2g mon %.2g (rel to value)\n",
                  a[k].point.theta_l_deg, a[k].point.theta_v_deg, a[k].m.exposure_s,
                  b[k].m.exposure_s, z, a[k].m.sigma_stat / a[k].m.value,
                  a[k].m.sigma_lamp / a[k].m.value, a[k].m.sigma_monitor / a[k].m.value);
  }
  const double rms = std::sqrt(z2 / static_cast<double>(a.size()));
  const double rms_stat = std::sqrt(z2_stat / static_cast<double>(a.size()));
  std::printf(
      "27 pairs: rms pull %.3f (%.3f with the statistical sigma alone); largest lamp share "
      "%.2f, monitor share %.2f\n",
      rms, rms_stat, lamp, monitor);
  // 27 unit-normal pulls give an rms within 0.60-1.43 with 99.8 % probability; the upper
  // bound allows the ~10 % of scatter the budget still leaves out (docs/measurement.md). The
  // statistical sigma alone gave 1.4-2.0 in the same runs: the instrument terms must carry a
  // real share of it, which the ratio asserts (observed 0.53-0.67).
  // The lower bound is 0.5, not 0.6: a slow build (ASan under load: 0.576 once in CI) lets the
  // lamp drift further within a point in simulated time, and the monitor term counts that drift
  // as scatter although the normalisation by the monitor's mean removes it - an overestimate
  // left for issue #16 (estimate the monitor's noise from successive differences). 0.5 still
  // catches a budget inflated by half.
  EXPECT_GT(rms, 0.5);
  EXPECT_LT(rms, 1.6);
  EXPECT_LT(rms / rms_stat, 0.8);
  // Both instrument terms are present somewhere in the run (not zero by construction).
  EXPECT_GT(lamp, 0.2);
  EXPECT_GT(monitor, 0.2);
}

// Issue #17: a plan is priced before its specimen was ever measured. One run of etched glass
// (Beckmann 0.493) and its fit give the bench's throughput; the ground glass's plan is then
// priced from its catalogue width (0.344) through it, and measured on a bench with the ground
// glass in it. The estimate's exposure time (frames, ranging tries, darks) must be within 30 % of
// the engine's; the plan's initial exposure, the only basis before, is far off. Then an adaptive
// plan of the ground glass with a target: its estimate simulates it (point_simulator.h,
// ForecastAdaptive) on the etched run's calibration, and must be within 30 % of the run too.
TEST(EstimateBeforeTheFirstRun, TheExpectedLobeAtTheBenchsThroughputPricesANewSpecimen) {
  const std::string db_path = (std::filesystem::temp_directory_path() /
                               ("gonio_estimate_" + std::to_string(::getpid()) + ".sqlite"))
                                  .string();
  std::filesystem::remove(db_path);
  auto opened = Storage::Open(db_path);
  ASSERT_TRUE(opened.ok());
  std::unique_ptr<Storage> store = std::move(*opened);
  const EngineOptions eo{.linear_limit_adu = 65000};
  auto print_stats = [](const gonio::testing::MeasuredRun& m) {
    std::printf("measured: %d ranging frames, darks %.0f s\n", m.stats.ranging_frames,
                m.stats.dark_exposure_s);
  };

  {  // The etched glass, measured and fitted: the throughput.
    gonio::testing::SimInstrument inst;
    gonio::testing::SimInstrumentOptions o;
    o.truth = sim::MicrofacetTruth("beckmann", 0.493, 1.51);
    ASSERT_TRUE(inst.Start(o).ok());
    auto etched = gonio::testing::MeasureThroughputRun(*store, inst, db_path, eo);
    ASSERT_TRUE(etched.ok()) << etched.error().message;
    print_stats(*etched);
    ASSERT_GT(etched->exposure_s, 0);
  }
  auto throughput = store->LatestThroughput();
  ASSERT_TRUE(throughput.ok()) << throughput.error().message;
  ASSERT_TRUE(throughput->has_value()) << "a finished run with a chosen fit gives a throughput";

  gonio::testing::SimInstrument inst;  // the ground glass, never measured
  ASSERT_TRUE(inst.Start(gonio::testing::SimInstrumentOptions{}).ok());
  auto planned = gonio::testing::ForecastPlan(db_path, "ground-glass-G1", inst.axes);
  ASSERT_TRUE(planned.ok()) << planned.error().message;
  const auto& [plan, points] = *planned;
  auto seen = store->LatestExposures("ground-glass-G1");
  ASSERT_TRUE(seen.ok());
  ASSERT_FALSE(seen->has_value());
  const auto forecast =
      ForecastFor(plan.specimen, *throughput, eo.linear_limit_adu, eo.max_ranging_tries);
  ASSERT_TRUE(forecast);
  EstimateParts priced, naive;
  EstimateSeconds(plan, points, inst.axes, plan.exposure.initial_s, nullptr, &*forecast, &priced);
  EstimateSeconds(plan, points, inst.axes, plan.exposure.initial_s, nullptr, nullptr, &naive);
  const auto measured_points =
      std::count_if(points.begin(), points.end(), [](const PlannedPoint& p) { return !p.skipped; });
  EXPECT_EQ(priced.from_forecast, measured_points);
  auto uniform = gonio::testing::MeasureAsGoniod(*store, inst, plan, points, eo);
  ASSERT_TRUE(uniform.ok()) << uniform.error().message;
  print_stats(*uniform);
  const std::int64_t run = uniform->run;
  const double exposed_s = uniform->exposure_s;
  // The run keeps its estimate beside what its points took, which adds up to the engine's count.
  auto info = store->GetRun(run);
  ASSERT_TRUE(info.ok());
  ASSERT_TRUE(info->estimate && info->exposed_s);
  EXPECT_EQ(info->estimate->basis,
            "the expected lobe (Beckmann alpha 0.344) at run 1's throughput");
  EXPECT_NEAR(info->estimate->exposure_s, priced.exposure_s, 1e-6 * priced.exposure_s);
  EXPECT_NEAR(*info->exposed_s, exposed_s, 1e-6 * exposed_s);
  std::printf("run summary: %s\n", DescribeExposureAgainstEstimate(*info).c_str());
  std::printf(
      "exposure time: measured %.0f s; forecast %.0f s (%+.0f %%, %d ranging frames, darks %.0f "
      "s); at the plan's initial exposure %.0f s (%+.0f %%)\n",
      exposed_s, priced.exposure_s, 100 * (priced.exposure_s / exposed_s - 1),
      priced.ranging_frames, priced.dark_exposure_s, naive.exposure_s,
      100 * (naive.exposure_s / exposed_s - 1));
  EXPECT_NEAR(priced.exposure_s / exposed_s, 1.0, 0.3);
  EXPECT_LT(naive.exposure_s / exposed_s, 0.3) << "the old basis was not far off: a weak test";

  {  // An adaptive plan of the ground glass, forecast by simulating it on a point simulator
     // calibrated on the etched glass's run (its throughput and its points' sigmas), then run to
     // its target on the same bench (one simulated camera per machine). One realisation: the spread
     // of real runs about the forecast is bench/forecast_spread.cc's (scripts/bench.sh forecast).
    auto aplanned = gonio::testing::ForecastPlan(db_path, "ground-glass-G1", inst.axes,
                                                 gonio::testing::kForecastAdaptive);
    ASSERT_TRUE(aplanned.ok()) << aplanned.error().message;
    const auto& [aplan, apoints] = *aplanned;
    EngineOptions with_axes = eo;
    with_axes.axes = inst.axes;  // the planner prices moves, as goniod configures it
    auto adaptive = gonio::testing::MeasureAsGoniod(*store, inst, aplan, apoints, with_axes);
    ASSERT_TRUE(adaptive.ok()) << adaptive.error().message;
    print_stats(*adaptive);
    const std::int64_t arun = adaptive->run;
    auto ainfo = store->GetRun(arun);
    ASSERT_TRUE(ainfo.ok() && ainfo->estimate && ainfo->exposed_s);
    auto events = store->Events(arun);
    ASSERT_TRUE(events.ok());
    std::string outcome;
    for (const RunEvent& e : *events)
      if (e.kind == "adaptive") outcome = e.detail;
    std::printf("adaptive run: %s; %s\n", outcome.c_str(),
                DescribeExposureAgainstEstimate(*ainfo).c_str());
    EXPECT_EQ(outcome.rfind("reached sigma(alpha)/alpha", 0), 0u) << outcome;
    // The coarse scan's points are candidates too: its point at the 45-degree lobe's peak tells
    // more of alpha per second than any other. Without them the run took four times its forecast.
    auto stored = store->Points(arun, /*pending_only=*/false);
    ASSERT_TRUE(stored.ok());
    int coarse_again = 0;
    for (const PlannedPoint& c : *stored) {
      if (c.index < static_cast<int>(apoints.size())) continue;  // the grid's, not a choice
      for (const PlannedPoint& g : apoints)
        if (!g.skipped && g.theta_l_deg == c.theta_l_deg && g.theta_v_deg == c.theta_v_deg)
          ++coarse_again;
    }
    EXPECT_GT(coarse_again, 0) << "no coarse-scan point was chosen again";
    EXPECT_NE(ainfo->estimate->basis.find("20 simulated runs"), std::string::npos)
        << ainfo->estimate->basis;
    // The criterion, on what the run's points took (as for the uniform plan above); the
    // budget, the estimate before, is 60 times the run.
    EXPECT_NEAR(ainfo->estimate->exposure_s / *ainfo->exposed_s, 1.0, 0.3);
    EXPECT_LT(ainfo->estimate->total_s, aplan.strategy.budget_s / 10);
  }
  store.reset();
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(db_path + ext);
}

// Issue #8, through the whole instrument: explicit rough surfaces of known sigma and tau, traced
// by the explicit-surface Monte Carlo (no microfacet formula anywhere), are what the simulated
// camera sees; the stages over Modbus, the CCD over GigE Vision, the engine, SQLite and the CSV
// export measure them; the fitter then recovers the alpha the surface statistics predict where
// single scattering holds (s = tau/sigma = 6), and reports a poor fit - not a confident wrong
// alpha - where it fails (s = 1: multiple scattering).
class EngineOnExplicitSurface : public EngineOnSim, public ::testing::WithParamInterface<double> {
 protected:
  std::shared_ptr<const sim::GroundTruth> Truth() override {
    sim::MonteCarloOptions o;
    o.rays = 400'000;
    o.n_phi = 1;  // normal incidence: symmetric in azimuth, so all rays feed the theta bins
    table = sim::ExplicitSurfaceMonteCarlo(GetParam(), 1.0, 1.51, 0, o);
    return std::make_shared<sim::TabulatedTruth>("explicit surfaces", table);
  }
  sim::BtdfTable table;
};

TEST_P(EngineOnExplicitSurface, FitterRecoversThePredictedAlphaOrReportsAPoorFit) {
  const double s = GetParam();
  auto [plan, run] = NewRun(
      "incidence_deg = [0]\nview_about = \"refracted\"\n"
      "view_from_deg = -40\nview_to_deg = 40\nview_step_deg = 2",
      "frames = 2\ninitial_s = 0.01\nmax_s = 10\nfloor = 0.004");
  Engine engine(*inst.stages, *inst.camera, inst.meter, *store,
                EngineOptions{.linear_limit_adu = 65000});
  std::atomic<bool> stop{false};
  const Status st = gonio::testing::RunResuming(engine, run, plan, stop);
  ASSERT_TRUE(st.ok()) << st.error().message;
  const std::string csv = db_path + ".csv";
  ASSERT_TRUE(store->ExportCsv(run, csv).ok());
  auto samples = fitting::ReadSamplesCsv(csv);
  std::filesystem::remove(csv);
  ASSERT_TRUE(samples.ok()) << samples.error().message;
  ASSERT_EQ(samples->size(), 41u);
  // The lobe: samples above 1 % of the peak. Below, the scene's stray-light floor (~1e-4 of the
  // peak, which no single-scattering model has; the demo fits it with a robust loss) would decide
  // chi-square instead of the surface.
  double peak = 0;
  for (const auto& x : *samples) peak = std::max(peak, x.value);
  std::vector<fitting::Sample> lobe;
  for (const auto& x : *samples)
    if (x.value > 0.01 * peak) lobe.push_back(x);
  // The stored sigma is statistical (0.01-0.1 %); the truth itself is known only to the table's
  // Monte Carlo error (1-2 % per 2-degree bin in the lobe) and its binning: 3 % stated.
  fitting::FitOptions o;
  o.eta = 1.51;
  auto f = fitting::Fit(fitting::WithSystematic(lobe, 0.03), o);
  ASSERT_TRUE(f.ok()) << f.error().message;
  const double predicted = sim::PredictedAlphaOfMesh(s, sim::SurfaceOptions{}.samples_per_tau);
  std::printf(
      "s %.1f: %zu samples in the lobe, alpha %.4f +- %.4f (predicted %.4f), chi2/dof %.2f,"
      " %s\n",
      s, lobe.size(), f->width.value, f->width.sigma, predicted, f->reduced_chi2,
      fitting::ToString(f->status));
  if (s >= 3) {
    EXPECT_EQ(f->status, fitting::FitStatus::kConverged) << f->message;
    // The prediction itself carries the few-percent slope spread of finite surfaces.
    EXPECT_NEAR(f->width.value / predicted, 1.0, 0.06);
  } else {
    EXPECT_EQ(f->status, fitting::FitStatus::kPoorFit) << "alpha " << f->width.value;
    EXPECT_GT(f->reduced_chi2, 10);
  }
}

INSTANTIATE_TEST_SUITE_P(Smoothness, EngineOnExplicitSurface, ::testing::Values(6.0, 1.0),
                         [](const auto& p) { return p.param > 3 ? "s6" : "s1"; });

}  // namespace
}  // namespace gonio::acquisition
