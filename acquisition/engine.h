// The sweep engine: measures a run's pending points in order, each one committed when complete,
// through the driver interfaces only. Per point: all axes move together, the readback is stored;
// the exposure is auto-ranged on a ladder of 8 steps per decade (no rectangle pixel past
// `saturation` of the linear range; the brightest pixel brought above a quarter of `target`,
// and flagged if it stays below `floor` at max_s); N frames are accumulated; a dark at the same
// exposure and temperature comes from the dark library (reused while fresh, retaken when stale
// or when the temperature moved); the source monitor, when present, is read around every frame
// and normalises by the lamp's output.
//
// The last frame of a point reads out while the stages move to the next one, when the camera
// reports the end of its exposures (devices::Camera::Expose): its reduction and commit happen
// then too, on a second thread. A frame lost in that readout is taken again after the stages
// return to its point.
//
// Stored value: (rectangle mean - dark mean) / exposure, in counts per second, divided by the
// monitor's mean reading in mW when there is a monitor (so runs on different days compare),
// proportional to BTDF * cos(theta_l) (docs/reference.md section 1). Its sigma is a budget of
// three components, stored apart (docs/measurement.md):
//   stat     shot, read and dark noise: the pooled per-pixel variance of the frames (each pixel
//            relative to its frame's mean, so that what all pixels share is left out) and the
//            dark's;
//   lamp     the lamp's fluctuation between the point's frames, which every pixel shares (so it
//            does not average over the rectangle): the frames' means' scatter beyond their
//            pixels' noise, pooled over the run's points of the same exposure (weighted by
//            how well each point resolves it: a faint point's excess is its pixels' noise);
//   monitor  the normalisation: the scatter of single monitor readings, pooled over the run, over
//            the point's number of readings;
// The pooled terms of a point are first estimated from the points before it (so that progress
// and an adaptive run's decisions have them); when Run returns, every point it stored takes the
// pools' final estimates (Storage::UpdateBudgets): the first points of a pool otherwise carry an
// estimate from a handful of frames, the clamp at 0 of which inflates them. The lamp's estimates
// by exposure are then fitted non-increasing in the exposure (NonIncreasingFit, reduce.h), so
// that an exposure only a point or two used borrows from its neighbours.
// A run resumed by another engine (a daemon restarted) keeps the earlier points' estimates.
//   background  with [background] measure = true (plan.h): after the point's frames the beam
//            block swings into the source beam and frames at the same exposure see the stray
//            light alone; their mean is subtracted (the dark then cancels and leaves stat) and
//            its uncertainty is this component: their pixels' noise, plus what moves all pixels
//            together (the frames' means' scatter beyond it, pooled over the run), over their
//            number. The flag leaves the beam with the next point's move.
// Both scatters come from successive differences (von Neumann): a drift of the lamp during the
// point moves the frames and the readings alike and the normalisation removes it, so the spread
// about the mean would count it twice as noise (docs/measurement.md).
// Pooling matters: a variance estimated from a point's own 4 or 5 readings has 3 or 4 degrees of
// freedom, and pulls normalised by it scatter 1.4 times wider than normal (Student's t).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <utility>
#include <vector>

#include "acquisition/plan.h"
#include "acquisition/reduce.h"
#include "acquisition/storage.h"
#include "devices/camera.h"
#include "devices/source_monitor.h"
#include "devices/stage.h"

namespace gonio::acquisition {

inline constexpr double kMonitorUnitW = 1e-3;  // values are per mW at the monitor

struct EngineOptions {
  double linear_limit_adu = 65535;  // the sensor's linear range (full well), raw ADU
  int max_ranging_tries = 12;
  // The stages' speeds (the configuration's axes), to price an adaptive run's moves against its
  // budget; empty: moves cost nothing.
  std::vector<devices::AxisSettings> axes = {};
};

// What the engine spent its time on (for the efficiency benchmark and logs).
struct EngineStats {
  int points = 0;
  int frames = 0, ranging_frames = 0, dark_frames = 0;  // frames = the averaged ones
  int background_frames = 0;                            // with the beam blocked
  int overlapped_readouts = 0;  // last frames read out while the stages moved on
  int retaken_frames = 0;       // of those, frames lost in that readout and taken again
  double exposure_s = 0;        // summed over every frame taken (averaged, ranging, dark)
  double dark_exposure_s = 0;   // of which darks
};

struct Progress {
  int done = 0, total = 0;  // measured points of the run (skipped ones not counted)
  PlannedPoint point;
  Measurement last;
  double elapsed_s = 0, eta_s = 0;
};

class Engine {
 public:
  // The devices and the database must outlive the engine; `monitor` may be null.
  Engine(devices::StageController& stages, devices::Camera& camera, devices::SourceMonitor* monitor,
         Storage& db, EngineOptions options = {});

  // Runs (or resumes) `run`. Returns OK when every point is done (the run is marked done), or
  // when `stop` was set (after the current point is stored; the run is left paused). A device
  // error stops the stages and leaves the run paused for a resume, with the error returned.
  Status Run(std::int64_t run, const Plan& plan, const std::atomic<bool>& stop,
             const std::function<void(const Progress&)>& progress = {});
  // A stop that does not wait for the point in hand (a daemon's SIGTERM): once *flag reads true,
  // the exposure in progress is stopped (Camera::SetInterrupt), the point's frames so far are
  // discarded, the point stays pending, and Run returns OK with the run paused. Null: none.
  void InterruptOn(const std::atomic<bool>* flag) { interrupt_ = flag; }
  // Shows `observer` the first averaged frame of every point (a console's live view), on the
  // engine's thread; the image is valid only during the call, which should be short.
  using FrameObserver =
      std::function<void(const cv::Mat1w& image, const PlannedPoint& point, double exposure_s)>;
  void ShowFramesTo(FrameObserver observer) { show_frame_ = std::move(observer); }

  const EngineStats& stats() const { return stats_; }

 private:
  bool Interrupted() const { return interrupt_ != nullptr && interrupt_->load(); }
  const std::atomic<bool>* interrupt_ = nullptr;
  FrameObserver show_frame_;

  // A point whose frames are all exposed; its last frame may still be reading out.
  struct Exposed {
    PlannedPoint point;
    Measurement m;  // geometry read back, exposure, ranging, flags, temperature
    RectAccumulator acc;
    // The frames with the beam blocked, when the plan measures the background (`background`):
    // then the last frame, and the one in readout, is one of these.
    RectAccumulator bg;
    bool background = false;
    const DarkRecord* dark = nullptr;
    std::vector<double> monitor;      // W: before every frame and after the last
    bool in_readout = false;          // the last frame is still to be retrieved
    std::pair<int, int> epoch{0, 0};  // DeviceEpoch() before the point's move
  };
  // The camera's and the stages' reconnections so far: a change during a point means a device
  // went away and came back (a power cycle loses the stages' positions), so the point is
  // measured again.
  std::pair<int, int> DeviceEpoch() const {
    return {camera_.Reconnections(), stages_.Reconnections()};
  }

  Status RunPoints(std::int64_t run, const Plan& plan, const std::atomic<bool>& stop,
                   const std::function<void(const Progress&)>& progress);
  // Moves all axes together and reads their positions back into m; the beam block, when the
  // bench has one, leaves the beam with them.
  Status MoveTo(const PlannedPoint& p, Measurement* m);
  // The beam block into the beam (true) or out of it; nothing without one.
  Status BlockBeam(bool blocked);
  // What a run's measurement starts from: the run as stored and its pending points.
  struct Begun {
    RunInfo info;
    std::vector<PlannedPoint> pending;
  };
  // The run taken up and marked running, its shutter opened; a camera that does not answer
  // leaves it paused (the error is the camera's).
  Result<Begun> BeginRun(std::int64_t run, const Plan& plan);
  // A device error at point `index`: the stages stopped, the run paused, the error named with
  // its run and point (an interrupt's as kAborted "interrupted").
  Status PauseOnFault(int index, const Error& err);
  // Auto-ranges, darks and exposes the point's frames at the stages' present position.
  Result<Exposed> ExposePoint(const PlannedPoint& p, const Plan& plan, Measurement m);
  // The accepted ranging try: its exposure, its frame (the first averaged one), the monitor read
  // just before it and the dark for its exposure.
  struct Ranged {
    double exposure_s = 0;
    devices::Frame first;
    std::optional<double> first_reading;
    const DarkRecord* dark = nullptr;
  };
  // From `t`, the exposure whose brightest rectangle pixel above dark lands within the policy's
  // band (or the last try allowed); sets m's ranging tries and its at-max flag.
  Result<Ranged> AutoRange(const PlannedPoint& p, const Plan& plan, const ExposurePolicy& x,
                           double t, Measurement& m);
  // The point's averaged frames into e (the first is the accepted try), the monitor read before
  // each and after the last; the last left in readout where the camera can.
  Status ExposeFrames(Exposed& e, const ExposurePolicy& x, double t, devices::Frame first,
                      std::optional<double> first_reading);
  // The background's frames with the beam blocked into e.bg; the last left in readout.
  Status ExposeBackground(Exposed& e, int frames, double t);
  // One frame into `into`, or, the `last` of a point's, left in readout (e.in_readout) where the
  // camera can say when its exposure ends.
  Status TakeFrame(Exposed& e, RectAccumulator& into, bool last);
  // Retrieves the last frame if it is in readout, then reduces and stores the point. A failed
  // retrieval leaves e.in_readout set (the caller retakes the frame); nothing is stored.
  Result<Measurement> Complete(Exposed& e);
  // The last frame again, at its point (the stages are brought back): after a lost readout.
  Result<Measurement> Retake(Exposed& e, const Error& why);
  Result<Measurement> Reduce(const Exposed& e);
  Result<const DarkRecord*> DarkFor(double exposure_s, const Plan& plan);
  Result<double> MonitorW();
  // An adaptive run's next decision (strategy.h), from what it has stored: the points chosen are
  // added to the run as pending, each with a 'chosen' event; or, when it stops, an 'adaptive'
  // event says why. Returns how many points were added (0: the run is complete).
  Result<int> ChooseMore(std::int64_t run, const Plan& plan);

  devices::StageController& stages_;
  devices::Camera& camera_;
  devices::SourceMonitor* monitor_;
  Storage& db_;
  EngineOptions o_;
  std::int64_t run_ = 0;
  std::optional<devices::BeamBlockSettings> beam_block_;  // the run's plan's (the bench's)
  // The flag known out of the beam: moved there in this run, with the stages' link unbroken since
  // (a controller that restarted may have lost it).
  bool flag_open_ = false;
  int flag_epoch_ = 0;
  int stale_frames_ = 0;  // camera_.StaleFrames() when the last stored point was logged
  std::optional<double> monitor_reference_;
  double last_exposure_s_ = 0;
  std::map<std::int64_t, DarkRecord> darks_;  // by exposure in microseconds
  // Pooled relative variances for the budget: sum2 / weight, each point adding its squared
  // deviations and its weight (degrees of freedom; for the lamp, degrees of freedom times the
  // squared signal, so that dim points, whose frames scatter by pixel noise alone, do not swamp
  // the estimate of a relative fluctuation).
  struct Pool {
    double sum2 = 0, weight = 0;
    double Variance() const { return weight > 0 ? std::max(0.0, sum2 / weight) : 0.0; }
  };
  Pool monitor_pool_;                        // of one monitor reading
  std::map<std::int64_t, Pool> lamp_pools_;  // of one frame's common mode, by exposure (us)
  Pool background_pool_;                     // of one background frame's common mode, absolute
  // What each point stored by this engine needs to take the pools' final estimates when Run
  // returns (RefreshBudgets): a point early in its pool got an estimate from few others.
  struct Pooled {
    int index = 0;
    double abs_value = 0, sigma_stat = 0;
    int frames = 0;
    std::int64_t lamp_key = 0;
    // The lamp's inputs: the frames' means' excess scatter over q, the pixels' noise of a frame's
    // mean, and the squared signal (all ADU^2; s2 = 0 where there were fewer than 2 frames).
    double excess = 0, q = 0, s2 = 0;
    double monitor_readings = 0;     // 0: no monitor
    std::optional<double> bg_pixel;  // the background's pixel variance of a frame's mean, ADU^2
    int bg_frames = 0;
    double exposure_norm = 1;  // exposure times the monitor's normalisation
  };
  std::vector<Pooled> pooled_;
  Pooled reduced_;  // Reduce's lamp inputs for Complete to record with the stored point
  Status RefreshBudgets();
  EngineStats stats_;
};

}  // namespace gonio::acquisition
