#include "acquisition/engine.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <future>
#include <set>
#include <tuple>

#include "acquisition/exposure.h"
#include "acquisition/strategy.h"

namespace gonio::acquisition {

namespace {

double UnixNow() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

bool HasAxis(const devices::StageController& s, const std::string& name) {
  for (const auto& a : s.axes())
    if (a.name == name) return true;
  return false;
}

}  // namespace

Engine::Engine(devices::StageController& stages, devices::Camera& camera,
               devices::SourceMonitor* monitor, Storage& db, EngineOptions options)
    : stages_(stages), camera_(camera), monitor_(monitor), db_(db), o_(options) {}

Result<double> Engine::MonitorW() {
  if (monitor_ == nullptr) return 0.0;
  return monitor_->PowerW();
}

Result<const DarkRecord*> Engine::DarkFor(double exposure_s, const Plan& plan) {
  auto temp = camera_.TemperatureC();
  if (!temp.ok()) return temp.error();
  const std::int64_t key = ExposureKey(exposure_s);
  auto it = darks_.find(key);
  const double now = UnixNow();
  if (it != darks_.end() && now - it->second.taken_unix_s <= plan.darks.max_age_s &&
      std::abs(*temp - it->second.temperature_c) <= plan.darks.max_temperature_change_c)
    return &it->second;  // fresh: reused
  // Stale, missing, or the sensor's temperature moved: take it again with the shutter closed.
  if (Status s = camera_.SetShutter(false); !s.ok()) return s.error();
  const cv::Rect rect(plan.rectangle.x, plan.rectangle.y, plan.rectangle.width,
                      plan.rectangle.height);
  RectAccumulator acc(rect, o_.linear_limit_adu);
  Status status = OkStatus();
  for (int k = 0; k < std::max(2, plan.darks.frames) && status.ok(); ++k) {
    auto f = camera_.Snap();
    if (!f.ok()) {
      status = f.error();
      break;
    }
    ++stats_.dark_frames;
    stats_.exposure_s += exposure_s;
    stats_.dark_exposure_s += exposure_s;
    acc.Add(f->image);
  }
  // The shutter reopens whatever happened: a closed shutter must not outlive the dark.
  if (Status s = camera_.SetShutter(true); !s.ok() && status.ok()) status = s;
  if (!status.ok()) return status.error();
  DarkRecord d;
  d.exposure_s = exposure_s;
  d.temperature_c = *temp;
  d.frames = acc.frames();
  d.mean = acc.Mean();
  d.pixel_var = acc.PixelVariance();
  d.taken_unix_s = now;
  auto id = db_.StoreDark(d);
  if (!id.ok()) return id.error();
  d.id = *id;
  darks_[key] = d;
  return &darks_[key];
}

Status Engine::MoveTo(const PlannedPoint& p, Measurement* m) {
  std::vector<std::pair<std::string, double>> targets = {{"sample", p.stage.sample_deg},
                                                         {"arm", p.stage.arm_deg}};
  if (HasAxis(stages_, "azimuth")) targets.emplace_back("azimuth", p.stage.azimuth_deg);
  // The flag leaves the beam with the move (a point's background left it in, or an earlier run
  // killed during one): the point's own frames must see the source.
  const bool known_open = flag_open_ && flag_epoch_ == stages_.Reconnections();
  const bool flag = beam_block_ && !known_open && HasAxis(stages_, "beam_block");
  if (flag) targets.emplace_back("beam_block", beam_block_->open_deg);
  if (Status s = stages_.MoveTo(targets); !s.ok()) return s;
  if (flag) {
    targets.pop_back();  // not read back into the measurement
    flag_open_ = true;
    flag_epoch_ = stages_.Reconnections();
  }
  for (const auto& [name, deg] : targets) {
    auto st = stages_.ReadStatus(name);
    if (!st.ok()) return st.error();
    (name == "sample" ? m->sample_read_deg
     : name == "arm"  ? m->arm_read_deg
                      : m->azimuth_read_deg) = st->position_deg;
  }
  return OkStatus();
}

Status Engine::BlockBeam(bool blocked) {
  if (!beam_block_) return OkStatus();
  flag_open_ = false;  // until the move is known done
  Status s =
      stages_.MoveTo({{"beam_block", blocked ? beam_block_->blocked_deg : beam_block_->open_deg}});
  flag_open_ = s.ok() && !blocked;
  flag_epoch_ = stages_.Reconnections();
  return s;
}

Result<Engine::Exposed> Engine::ExposePoint(const PlannedPoint& p, const Plan& plan,
                                            Measurement m) {
  // An adaptive plan's coarse scan is exposed short; the points it chose start at their planned
  // exposure, so that ranging only checks it.
  const ExposurePolicy x = ExposureFor(plan, p);
  const double limit = o_.linear_limit_adu;
  const cv::Rect rect(plan.rectangle.x, plan.rectangle.y, plan.rectangle.width,
                      plan.rectangle.height);
  const double spent_before = stats_.exposure_s;  // what this point takes, darks included
  double t = p.planned_exposure_s   ? *p.planned_exposure_s
             : last_exposure_s_ > 0 ? last_exposure_s_
                                    : OnLadder(x.initial_s);
  t = std::clamp(t, x.min_s, x.max_s);
  auto ranged = AutoRange(p, plan, x, t, m);
  if (!ranged.ok()) return ranged.error();
  t = ranged->exposure_s;
  last_exposure_s_ = t;
  // The exposure the camera applied, not the one asked for: cameras set it in steps (the simulated
  // one in whole microseconds: the ladder's 3.162 ms came out 0.28 us short, 9e-5 of the peak's
  // value; a real camera's step may be a sensor line), and the value is counts per second of it.
  // The engine's keys (darks, lamp pools) stay the step asked for (ExposureKey); the planner
  // compares stored exposures within 0.1 % (SameExposure). A camera that cannot say keeps the
  // request.
  if (auto applied = camera_.Exposure(); applied.ok() && *applied > 0) t = *applied;
  m.exposure_s = t;

  // The monitor is read before every frame and after the last: its mean normalises the point,
  // and its spread (flicker the exposures average out but a short reading does not) enters sigma.
  // n frames of T have n + 1 readings at 0, T, ..., nT: their mean is the frames' middle, and no
  // two are taken together. (They were once: the first frame, the last ranging try, was read
  // after it and the second before it, back to back. Two readings of one instant count once
  // in the mean's error but twice in n, and their difference, near 0, pulled the pooled
  // reading variance down: on antiglare's 20 s points, 4 frames, the normalisation's error
  // came out 1.3 to 1.5 times its sigma over twenty runs.)
  const int background_frames = BackgroundFrames(plan);
  Exposed e{p,
            m,
            RectAccumulator(rect, limit),
            RectAccumulator(rect, limit),
            background_frames > 0,
            ranged->dark,
            {},
            false};
  if (Status s = ExposeFrames(e, x, t, std::move(ranged->first), ranged->first_reading); !s.ok())
    return s.error();
  if (e.background)
    if (Status s = ExposeBackground(e, background_frames, t); !s.ok()) return s.error();
  auto temp = camera_.TemperatureC();
  if (!temp.ok()) return temp.error();
  e.m.temperature_c = *temp;
  e.m.exposed_s = stats_.exposure_s - spent_before;
  return e;
}

Result<Engine::Ranged> Engine::AutoRange(const PlannedPoint& p, const Plan& plan,
                                         const ExposurePolicy& x, double t, Measurement& m) {
  const double limit = o_.linear_limit_adu;
  const cv::Rect rect(plan.rectangle.x, plan.rectangle.y, plan.rectangle.width,
                      plan.rectangle.height);
  Ranged r;
  // Auto-ranging: the brightest rectangle pixel above dark goes to `target` of the linear range
  // above dark; a pixel past `saturation` shortens the exposure, one below `floor` lengthens it.
  for (int tries = 1;; ++tries) {
    if (Status s = camera_.SetExposure(t); !s.ok()) return s.error();
    // The dark first: the accepted try is the first averaged frame, and a dark taken after it
    // would part it from the monitor's readings by the dark's frames (20 s exposures: a lamp
    // drifting 12 %/h moved 0.3 % in between; EngineDriftingLamp under load).
    auto d = DarkFor(t, plan);
    if (!d.ok()) return d.error();
    r.dark = *d;
    // Read before each try, since the accepted one becomes the first averaged frame: its reading
    // must come before it, as every other frame's does (see the frames' loop below).
    if (monitor_ != nullptr) {
      auto w = MonitorW();
      if (!w.ok()) return w.error();
      r.first_reading = *w;
    }
    auto f = camera_.Snap();
    if (!f.ok()) return f.error();
    ++stats_.ranging_frames;  // the accepted one is counted as averaged below
    stats_.exposure_s += t;
    RectAccumulator probe(rect, limit);
    probe.Add(f->image);
    const double range = limit - r.dark->mean;
    const double peak = probe.Max() - r.dark->mean;
    m.ranging_tries = tries;
    const ExposureJudgement j = JudgeExposure(x, t, peak, range);
    if (tries >= o_.max_ranging_tries || (!j.too_bright && !j.too_dim)) {
      if (j.too_bright)
        return Error{ErrorCode::kDeviceFault, "point " + std::to_string(p.index) +
                                                  " saturates even at " + std::to_string(t) +
                                                  " s (min_s " + std::to_string(x.min_s) + ")"};
      if (peak < x.floor * range) m.flags |= kFlagAtMaxExposure;
      r.first = std::move(f).value();
      r.exposure_s = t;
      return r;
    }
    if (j.too_bright && t <= x.min_s)
      return Error{ErrorCode::kDeviceFault, "point " + std::to_string(p.index) +
                                                " saturates at the shortest exposure " +
                                                std::to_string(x.min_s) + " s"};
    t = j.next_s;
  }
}

Status Engine::ExposeFrames(Exposed& e, const ExposurePolicy& x, double t, devices::Frame first,
                            std::optional<double> first_reading) {
  const PlannedPoint& p = e.point;
  if (first_reading) e.monitor.push_back(*first_reading);
  for (int k = 0; k < x.frames; ++k) {
    if (Interrupted()) return Error{ErrorCode::kAborted, "interrupted between frames"};
    if (monitor_ != nullptr && k > 0) {
      auto w = MonitorW();
      if (!w.ok()) return w.error();
      e.monitor.push_back(*w);
    }
    ++stats_.frames;
    if (k == 0) {
      --stats_.ranging_frames;  // the last ranging frame is the first averaged one
      e.acc.Add(first.image);
      if (show_frame_) show_frame_(first.image, p, t);
      first.image.release();  // frames are not kept beyond their reduction
      continue;
    }
    stats_.exposure_s += t;
    if (Status s = TakeFrame(e, e.acc, k == x.frames - 1 && !e.background); !s.ok()) return s;
  }
  if (monitor_ != nullptr) {
    auto w = MonitorW();
    if (!w.ok()) return w.error();
    e.monitor.push_back(*w);
  }
  return OkStatus();
}

// The same exposure with the beam blocked ahead of the sample. Its last frame reads out while the
// stages (and the flag, out of the beam) move on.
Status Engine::ExposeBackground(Exposed& e, int frames, double t) {
  if (Status s = BlockBeam(true); !s.ok()) return s;
  for (int k = 0; k < frames; ++k) {
    if (Interrupted()) return Error{ErrorCode::kAborted, "interrupted between frames"};
    ++stats_.background_frames;
    stats_.exposure_s += t;
    if (Status s = TakeFrame(e, e.bg, k == frames - 1); !s.ok()) return s;
  }
  return OkStatus();
}

// The last frame is left to read out while the stages move on. A camera that cannot say when its
// exposure ends, or a failed Expose (nothing has moved), takes it whole.
Status Engine::TakeFrame(Exposed& e, RectAccumulator& into, bool last) {
  if (last && camera_.ReportsExposureEnd() && camera_.Expose().ok()) {
    e.in_readout = true;
    ++stats_.overlapped_readouts;
    return OkStatus();
  }
  auto f = camera_.Snap();
  if (!f.ok()) return f.error();
  into.Add(f->image);
  return OkStatus();
}

Result<Measurement> Engine::Reduce(const Exposed& e) {
  Measurement m = e.m;
  reduced_ = {};
  const double t = m.exposure_s;
  const DarkRecord* dark = e.dark;
  double norm = 1, monitor_rel_var = 0;
  if (monitor_ != nullptr) {
    double sum = 0;
    for (double w : e.monitor) sum += w;
    const double n = static_cast<double>(e.monitor.size());
    m.monitor_w = sum / n;
    if (!(*m.monitor_w > 0))
      return Error{ErrorCode::kDeviceFault,
                   "source monitor reads " + std::to_string(*m.monitor_w) + " W: lamp off?"};
    // One reading's relative variance, pooled over the run; the mean's is that over n. From
    // successive differences (von Neumann): a drift of the lamp during the point moves the
    // readings and the frames alike, and the normalisation removes it, so it is not noise here.
    for (std::size_t i = 1; i < e.monitor.size(); ++i)
      monitor_pool_.sum2 += 0.5 * std::pow((e.monitor[i] - e.monitor[i - 1]) / *m.monitor_w, 2);
    monitor_pool_.weight += n - 1;
    monitor_rel_var = monitor_pool_.Variance() / n;
    if (!monitor_reference_) {  // kept for the record: the run's first reading
      monitor_reference_ = *m.monitor_w;
      if (Status s = db_.SetMonitorReference(run_, *monitor_reference_); !s.ok()) return s.error();
    }
    norm = *m.monitor_w / kMonitorUnitW;  // counts per second per mW at the monitor
  }
  const RectAccumulator& acc = e.acc;
  m.frames = acc.frames();
  m.rect_mean = acc.Mean();
  m.rect_sd = acc.FrameMeansSd();
  m.rect_pixels = acc.pixels();
  m.rect_saturated = acc.Saturated();
  m.dark_id = dark->id;
  // One frame has no variance between frames: its own pixels' (reduce.h, FrameSpatialVariance),
  // which hold the signal's shot noise. The dark's pixel variance, used here before, has none: an
  // adaptive coarse scan's bright points were stored at a sixth of their sigma, and the planner's
  // noise model, fitted to them, priced the peak 20 times too cheap (docs/acquisition.md).
  const double spatial = acc.FirstFrameSpatialVariance();
  m.pixel_var = acc.frames() >= 2 ? acc.PixelVariance() : spatial >= 0 ? spatial : dark->pixel_var;
  m.value = (m.rect_mean - dark->mean) / t / norm;
  // With a measured background the dark is subtracted from both and cancels: the point's own
  // frames' noise is all of stat.
  // The dark set's own error is in every point subtracted with it: sigma_dark says how much of
  // sigma_stat it is, so that a fit can take it as one error per set (antiglare runs
  // at ambient: the 20 s set's offset, shared by 13 points, scattered 2.1 times its own error
  // from run to run).
  const double var_dark =
      e.background ? 0.0 : dark->pixel_var / (m.rect_pixels * static_cast<double>(dark->frames));
  const double var_mean = m.pixel_var / (m.rect_pixels * static_cast<double>(m.frames)) + var_dark;
  m.sigma_stat = std::sqrt(var_mean) / (t * norm);
  m.sigma_dark = std::sqrt(var_dark) / (t * norm);
  double level = dark->mean;  // what the lamp's signal is counted above
  if (e.background) {
    const RectAccumulator& b = e.bg;
    if (b.frames() < 2)
      return Error{ErrorCode::kDeviceFault, "point " + std::to_string(e.point.index) +
                                                ": its background has " +
                                                std::to_string(b.frames()) + " frame(s), not 2"};
    // Normalised as the point is (by the monitor's readings during its frames), so that the
    // subtraction is exact for stray light that follows the lamp and the dark cancels.
    m.background = (b.Mean() - dark->mean) / t / norm;
    m.value -= *m.background;
    // Pixel noise, and what moves every pixel together (ambient light, a flickering stray path):
    // the frames' means' scatter beyond their pixels' noise, pooled over the run's backgrounds
    // (from successive differences, as the lamp's: a few frames' own would scatter widely).
    const double pixel = b.PixelVariance() / m.rect_pixels;
    background_pool_.sum2 += (b.frames() - 1) * (b.FrameMeansVariance() - pixel);
    background_pool_.weight += b.frames() - 1;
    const double var_b = (pixel + background_pool_.Variance()) / b.frames();
    m.sigma_background = std::sqrt(var_b) / (t * norm);
    level = b.Mean();
  }
  m.sigma_monitor = std::abs(m.value) * std::sqrt(monitor_rel_var);
  // The lamp between frames: each frame's mean scatters by its pixels' noise q = pixel_var / P
  // and by what all pixels share (c s^2 for a relative fluctuation c of the signal s). c is
  // pooled by exposure as a weighted least-squares fit of excess = c s^2: the excess over n
  // frames scatters by sqrt(2 / (n - 1)) (q + c s^2), so a faint point, whose excess is its
  // pixels' noise, weighs less than a bright one: here (s^2 / q)^2, the provisional estimate;
  // RefreshBudgets iterates with the whole variance when the run ends. An unweighted ratio
  // (sum of excesses over sum of s^2) let a lobe's tails, sharing an exposure with its flank,
  // add their noise to the flank's c: with a steady lamp the lamp term reached the point's
  // statistical sigma (tests/acquisition/engine_sim_test.cc,
  // ASteadyLampAddsNoLampTermAtOneExposure).
  const double signal = m.rect_mean - level;
  if (m.frames >= 2) {
    Pool& pool = lamp_pools_[ExposureKey(dark->exposure_s)];  // the step asked for
    const double excess = acc.FrameMeansVariance() - m.pixel_var / m.rect_pixels;  // drift-free
    const double s2 = signal * signal;
    const double q = m.pixel_var / m.rect_pixels;
    reduced_.excess = excess, reduced_.q = q, reduced_.s2 = s2;
    if (q > 0 && s2 > 0) {
      pool.sum2 += (m.frames - 1) * s2 * excess / (q * q);
      pool.weight += (m.frames - 1) * s2 * s2 / (q * q);
    }
    m.sigma_lamp = std::abs(m.value) * std::sqrt(pool.Variance() / m.frames);
  }
  m.sigma = std::sqrt(m.sigma_stat * m.sigma_stat + m.sigma_lamp * m.sigma_lamp +
                      m.sigma_monitor * m.sigma_monitor + m.sigma_background * m.sigma_background);
  return m;
}

Result<Measurement> Engine::Complete(Exposed& e) {
  if (const auto now = DeviceEpoch(); now != e.epoch) {
    e.in_readout = false;  // not retaken: the whole point is measured again
    const bool camera = now.first != e.epoch.first, stages = now.second != e.epoch.second;
    return Error{ErrorCode::kDeviceFault,
                 std::string(camera && stages ? "the camera and the stages were"
                             : camera         ? "the camera was"
                                              : "the stages were") +
                     " connected again while this point was measured (" +
                     (camera && !camera_.LastReconnectionCause().empty()
                          ? "the camera's cause: " + camera_.LastReconnectionCause()
                          : std::string("a device restarted?")) +
                     "); it stays pending and is measured again"};
  }
  if (e.in_readout) {
    auto f = camera_.Retrieve();
    if (!f.ok()) return f.error();
    (e.background ? e.bg : e.acc).Add(f->image);
    e.in_readout = false;
  }
  auto m = Reduce(e);
  if (!m.ok()) return m;
  if (Status s = db_.StoreMeasurement(run_, *m); !s.ok()) return s.error();
  Pooled p{.index = m->index,
           .abs_value = std::abs(m->value),
           .sigma_stat = m->sigma_stat,
           .frames = m->frames,
           .lamp_key = ExposureKey(e.dark->exposure_s),  // the step asked for, as the darks
           .excess = reduced_.excess,
           .q = reduced_.q,
           .s2 = reduced_.s2,
           .monitor_readings = m->monitor_w ? static_cast<double>(e.monitor.size()) : 0.0,
           .bg_pixel = std::nullopt,
           .bg_frames = 0,
           .exposure_norm = m->exposure_s * (m->monitor_w ? *m->monitor_w / kMonitorUnitW : 1.0)};
  if (e.background) p.bg_pixel = e.bg.PixelVariance() / m->rect_pixels, p.bg_frames = e.bg.frames();
  pooled_.push_back(p);
  if (const int stale = camera_.StaleFrames(); stale != stale_frames_) {
    (void)db_.AddEvent(run_, "camera",
                       "point " + std::to_string(e.point.index) + ": " +
                           std::to_string(stale - stale_frames_) +
                           " frame(s) exposed before their trigger (late frames of an earlier "
                           "one) were refused; the point's frames are its own");
    stale_frames_ = stale;
  }
  return m;
}

Status Engine::RefreshBudgets() {
  // The lamp's relative variance c by exposure, now with each point's excess weighted by its
  // whole variance, 2 (q + c s^2)^2 / (n - 1), iterated from the run's pooled estimate: where the
  // lamp is resolved, the brightest points' excess scatters with their lamp term too, and
  // weights by q alone let two or three of them decide c (on antiglare c at 0.056 s moved by
  // half between runs). Then fitted non-increasing in the exposure (reduce.h): an exposure that
  // a point or two met borrows from its neighbours instead of carrying its own few frames'
  // noise. Unclamped until fitted, so that noise below 0 pulls as noise above does.
  std::vector<std::int64_t> keys;
  std::vector<double> c, weight;
  for (const auto& [key, pool] : lamp_pools_) {  // by exposure, increasing
    if (!(pool.weight > 0)) continue;
    double ck = pool.sum2 / pool.weight, info = pool.weight;
    for (int round = 0; round < 5; ++round) {
      double num = 0, den = 0;
      for (const Pooled& p : pooled_) {
        if (p.lamp_key != key || !(p.q > 0 && p.s2 > 0)) continue;
        const double v = p.q + std::max(0.0, ck) * p.s2;
        num += (p.frames - 1) * p.s2 * p.excess / (v * v);
        den += (p.frames - 1) * p.s2 * p.s2 / (v * v);
      }
      if (!(den > 0)) break;  // the pool's points were stored by an earlier engine
      ck = num / den, info = den;
    }
    keys.push_back(key);
    c.push_back(ck);
    weight.push_back(info);
  }
  std::map<std::int64_t, double> lamp;
  const std::vector<double> fitted = NonIncreasingFit(c, weight);
  for (std::size_t i = 0; i < keys.size(); ++i) lamp[keys[i]] = std::max(0.0, fitted[i]);
  std::vector<Storage::BudgetUpdate> updates;
  updates.reserve(pooled_.size());
  for (const Pooled& p : pooled_) {
    Storage::BudgetUpdate b{.index = p.index, .sigma_background = std::nullopt};
    if (p.frames >= 2) {
      const auto it = lamp.find(p.lamp_key);
      if (it != lamp.end()) b.sigma_lamp = p.abs_value * std::sqrt(it->second / p.frames);
    }
    if (p.monitor_readings > 0)
      b.sigma_monitor = p.abs_value * std::sqrt(monitor_pool_.Variance() / p.monitor_readings);
    if (p.bg_pixel)
      b.sigma_background =
          std::sqrt((*p.bg_pixel + background_pool_.Variance()) / p.bg_frames) / p.exposure_norm;
    const double bg = b.sigma_background.value_or(0);
    b.sigma = std::sqrt(p.sigma_stat * p.sigma_stat + b.sigma_lamp * b.sigma_lamp +
                        b.sigma_monitor * b.sigma_monitor + bg * bg);
    updates.push_back(b);
  }
  if (updates.empty()) return OkStatus();
  return db_.UpdateBudgets(run_, updates);
}

Result<Measurement> Engine::Retake(Exposed& e, const Error& why) {
  (void)db_.AddEvent(run_, "retake",
                     "point " + std::to_string(e.point.index) + ": its last frame was lost in " +
                         "readout (" + why.message + "); taken again at the point");
  Measurement back;
  if (Status s = MoveTo(e.point, &back); !s.ok()) return s.error();
  // A background frame is retaken with the beam blocked again.
  if (e.background)
    if (Status s = BlockBeam(true); !s.ok()) return s.error();
  // Nothing else touched the camera since: it is still at the point's exposure.
  auto f = camera_.Snap();
  if (!f.ok()) return f.error();
  ++stats_.retaken_frames;
  stats_.exposure_s += e.m.exposure_s;
  e.m.exposed_s += e.m.exposure_s;
  (e.background ? e.bg : e.acc).Add(f->image);
  e.in_readout = false;
  if (monitor_ != nullptr && !e.background) {
    auto w = MonitorW();
    if (!w.ok()) return w.error();
    e.monitor.push_back(*w);
  }
  return Complete(e);
}

Status Engine::Run(std::int64_t run, const Plan& plan, const std::atomic<bool>& stop,
                   const std::function<void(const Progress&)>& progress) {
  // The camera's waits end on the same interrupt as the engine's, for this run only.
  struct CameraInterrupt {
    devices::Camera& camera;
    ~CameraInterrupt() { camera.SetInterrupt(nullptr); }
  } interrupt_guard{camera_};
  camera_.SetInterrupt(interrupt_);
  if (run != run_) pooled_.clear();  // a resume on this engine refreshes its earlier points too
  Status s = RunPoints(run, plan, stop, progress);
  if (Status r = RefreshBudgets(); !r.ok())
    (void)db_.AddEvent(run, "budget",
                       "the pooled terms' final estimates were not stored (each point keeps the "
                       "estimate it was measured with): " +
                           r.error().ToString());
  // Interrupted: the run was left paused with its point pending (the fault handler below).
  if (!s.ok() && s.error().code == ErrorCode::kAborted && Interrupted()) return OkStatus();
  return s;
}

// The run's state taken up (its reference, the beam block, the stale-frame count), its pending
// points read, the run marked running (a "resumed" event when some are done) and the shutter
// opened; a camera that does not answer leaves it paused.
Result<Engine::Begun> Engine::BeginRun(std::int64_t run, const Plan& plan) {
  run_ = run;
  beam_block_ = plan.beam_block;
  flag_open_ = false;  // not known: the run's first move takes it out of the beam
  stale_frames_ = camera_.StaleFrames();  // counted per run
  auto info = db_.GetRun(run);
  if (!info.ok()) return info.error();
  monitor_reference_ = info->monitor_reference_w;  // a resumed run keeps its reference
  auto pending = db_.Points(run, /*pending_only=*/true);
  if (!pending.ok()) return pending.error();
  if (Status s = db_.SetRunStatus(run, RunStatus::kRunning); !s.ok()) return s.error();
  if (info->points_done > 0)
    (void)db_.AddEvent(run, "resumed", std::to_string(info->points_done) + " points already done");
  // The shutter starts open (a previous run may have been killed during a dark). A camera that
  // does not answer leaves the run paused, as a fault at a point does, not marked running.
  if (Status s = camera_.SetShutter(true); !s.ok()) {
    (void)stages_.StopAll();
    (void)db_.AddEvent(run, "fault", s.error().ToString());
    (void)db_.SetRunStatus(run, RunStatus::kPaused);
    return s.error();
  }
  return Begun{std::move(info).value(), std::move(pending).value()};
}

// A device error at point `index`: the stages stopped, the run paused for a resume, and the
// error named with its run and point (an interrupt's, as such).
Status Engine::PauseOnFault(int index, const Error& err) {
  (void)stages_.StopAll();
  if (err.code == ErrorCode::kAborted && Interrupted()) {
    (void)db_.AddEvent(run_, "paused",
                       "interrupted during point " + std::to_string(index) +
                           " (a stop that does not wait for it): its frames so far are "
                           "discarded; it stays pending");
    (void)db_.SetRunStatus(run_, RunStatus::kPaused);
    return Error{ErrorCode::kAborted, "interrupted"};
  }
  (void)db_.AddEvent(run_, "fault", err.ToString());
  (void)db_.SetRunStatus(run_, RunStatus::kPaused);
  return Error{err.code, "run " + std::to_string(run_) + ", point " + std::to_string(index) + ": " +
                             err.message};
}

Status Engine::RunPoints(std::int64_t run, const Plan& plan, const std::atomic<bool>& stop,
                         const std::function<void(const Progress&)>& progress) {
  auto begun = BeginRun(run, plan);
  if (!begun.ok()) return begun.error();
  auto& [info, pending] = *begun;
  Progress pr;
  pr.total = info.points_total - info.points_skipped;
  pr.done = info.points_done;
  const auto t0 = std::chrono::steady_clock::now();
  int measured_here = 0;

  auto fault = [this](int index, const Error& err) { return PauseOnFault(index, err); };
  // The previous point while its last frame reads out, and its completion on a second thread
  // (declared after it: the future's destructor waits for the thread before the point goes).
  std::optional<Exposed> tail;
  std::future<Result<Measurement>> tail_done;
  // Waits for the previous point to be stored; a last frame lost in readout is retaken at its
  // point, which moves the stages back (*moved_back).
  auto settle = [&](bool* moved_back) -> Status {
    if (!tail) return OkStatus();
    auto m = tail_done.get();
    if (!m.ok() && tail->in_readout && !Interrupted()) {
      *moved_back = true;
      m = Retake(*tail, m.error());
    }
    const PlannedPoint point = tail->point;
    tail.reset();
    if (!m.ok()) return fault(point.index, m.error());
    ++stats_.points;
    ++pr.done;
    ++measured_here;
    if (progress) {
      pr.point = point;
      pr.last = *m;
      pr.elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      pr.eta_s = pr.elapsed_s / measured_here * (pr.total - pr.done);
      progress(pr);
    }
    return OkStatus();
  };

  // The flag out of the beam when the run ends or pauses on request, so that a live view, or a
  // program that does not know of it, sees the source; a flag that does not move is logged (the
  // next run's first move tries again).
  auto open_flag = [&] {
    if (BackgroundFrames(plan) == 0) return;
    if (Status s = BlockBeam(false); !s.ok())
      (void)db_.AddEvent(run, "beam_block",
                         "the flag could not leave the beam: " + s.error().ToString());
  };
  bool moved_back = false;
  for (;;) {  // an adaptive run measures what it chose, then chooses again
    for (const PlannedPoint& p : pending) {
      if (stop) {
        if (Status s = settle(&moved_back); !s.ok()) return s;
        (void)db_.AddEvent(run, "paused",
                           "stopped by request before point " + std::to_string(p.index));
        open_flag();
        return db_.SetRunStatus(run, RunStatus::kPaused);
      }
      Measurement m;
      m.index = p.index;
      auto epoch = DeviceEpoch();
      Status moved = MoveTo(p, &m);  // while the previous point's last frame reads out
      moved_back = false;
      if (Status s = settle(&moved_back); !s.ok()) return s;
      // The previous point's retake may have opened the camera again: none of this point's frames
      // were taken before it, so its epoch starts here (the stages' with the move back, if any).
      epoch.first = DeviceEpoch().first;
      if (moved.ok() && moved_back) {
        epoch = DeviceEpoch();
        moved = MoveTo(p, &m);
      }
      if (!moved.ok()) return fault(p.index, moved.error());
      auto e = ExposePoint(p, plan, m);
      if (!e.ok()) return fault(p.index, e.error());
      tail.emplace(std::move(e).value());
      tail->epoch = epoch;
      const bool overlap = tail->in_readout;
      tail_done = std::async(overlap ? std::launch::async : std::launch::deferred,
                             [this, t = &*tail] { return Complete(*t); });
      // Without a readout to overlap, the point is stored before anything moves.
      if (!overlap)
        if (Status s = settle(&moved_back); !s.ok()) return s;
    }
    if (Status s = settle(&moved_back); !s.ok()) return s;
    if (plan.strategy.kind != StrategyKind::kAdaptive) break;
    auto chosen = ChooseMore(run, plan);
    if (!chosen.ok()) return chosen.error();  // storage: the run stays as it was, to resume
    if (*chosen == 0) break;
    pr.total += *chosen;
    auto more = db_.Points(run, /*pending_only=*/true);
    if (!more.ok()) return more.error();
    pending = std::move(more).value();
  }
  open_flag();
  return db_.SetRunStatus(run, RunStatus::kDone);
}

Result<int> Engine::ChooseMore(std::int64_t run, const Plan& plan) {
  // A run killed after deciding to stop and before it was marked done has decided already.
  auto events = db_.Events(run);
  if (!events.ok()) return events.error();
  for (const RunEvent& e : *events)
    if (e.kind == "adaptive") return 0;
  auto rows = db_.Measurements(run);
  if (!rows.ok()) return rows.error();
  auto all = db_.Points(run, /*pending_only=*/false);
  if (!all.ok()) return all.error();
  // What the run has seen, in the order it was measured, each point's cost its exposures (stored
  // exposed_s) and its move from the point before.
  std::vector<Observation> seen;
  StageTargets at{0, 180, 0};
  for (const MeasurementRow& r : *rows) {
    Observation o;
    o.point = r.point;
    o.value = r.m.value;
    o.sigma = r.m.sigma;
    o.exposure_s = r.m.exposure_s;
    o.frames = r.m.frames;
    const double dark = r.dark_rect_mean.value_or(0);
    o.level = (r.m.rect_mean - dark) / std::max(1.0, o_.linear_limit_adu - dark);
    o.cost_s = r.m.exposed_s + MoveSeconds(o_.axes, at, r.point.stage);
    at = r.point.stage;
    seen.push_back(o);
  }
  // The candidates are the grid's points the coarse scan left and the ones it measured: a coarse
  // point may be the most telling of all (the lobe's peak at a second incidence). Left out, a
  // first run of the ground glass chose 413 points at normal incidence for 697 s of exposure,
  // where 37 there and 17 at 45 degrees (a coarse point) give its sigma in 138 s; the forecast's
  // simulated runs could choose them and priced the run at a quarter of what it took. A point
  // chosen again is the same candidate (one per geometry).
  std::vector<PlannedPoint> candidates;
  std::set<std::tuple<double, double, double, bool>> geometries;
  for (const PlannedPoint& p : *all) {
    if (p.skipped && p.reason != kCandidateReason) continue;
    if (!geometries.emplace(p.theta_l_deg, p.theta_v_deg, p.phi_deg, p.reflection).second) continue;
    PlannedPoint c = p;
    c.skipped = true, c.reason = kCandidateReason, c.predicted_s = 0, c.planned_exposure_s.reset();
    candidates.push_back(c);
  }
  auto step = NextAdaptiveStep(plan, candidates, seen);
  if (!step.ok()) {  // the planner cannot go on (a fit that fails): the run ends with what it has
    (void)db_.AddEvent(run, "adaptive", "stopped early: " + step.error().message);
    return 0;
  }
  if (step->stop) {
    (void)db_.AddEvent(run, "adaptive", step->stop->message);
    return 0;
  }
  std::vector<PlannedPoint> points;
  std::vector<std::string> reasons;
  for (const Choice& c : step->batch) points.push_back(c.point), reasons.push_back(c.Reason());
  auto added = db_.AddChosenPoints(run, points, reasons);
  if (!added.ok()) return added.error();
  return static_cast<int>(added->size());
}

}  // namespace gonio::acquisition
