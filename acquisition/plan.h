// A measurement plan (TOML, acquisition/README.md documents every key; example:
// config/plan_ground_glass.toml): which specimen, which geometries, how to expose, which image
// rectangle to average. Loading validates the whole file against the specimen catalogue and the
// instrument (travel limits, the arm in the source beam) and the camera's image size, so that a bad
// plan is refused with file:line before anything moves. Geometries that cannot be measured are
// kept with the reason they are skipped.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "common/bench_angles.h"
#include "common/result.h"
#include "devices/stage.h"
#include "fitting/response.h"

namespace gonio::acquisition {

// One specimen of the catalogue (config/samples.toml).
struct Specimen {
  std::string name;
  std::string material;
  double thickness_mm = 6;
  double eta = 1.5;
  // The Beckmann width the specimen is expected to have (the catalogue's), for rectangles chosen
  // by the plan ([rectangle] auto); nullopt: unknown.
  std::optional<double> expected_alpha;
};
Result<std::vector<Specimen>> LoadSpecimens(const std::string& path);

struct ExposurePolicy {
  int frames = 4;           // averaged per point
  double initial_s = 0.05;  // the first point's first try
  double min_s = 1e-4, max_s = 20;
  double saturation = 0.9;  // no rectangle pixel may exceed this fraction of full scale
  double target = 0.5;      // the rectangle's brightest pixel is aimed here (above dark)
  double floor = 0.02;      // below this, the exposure is lengthened unless at max_s
};

struct DarkPolicy {
  int frames = 4;
  double max_age_s = 600;  // a dark older than this is retaken
  double max_temperature_change_c = 0.5;
};

// [background]: each point's stray-light background measured on the bench's beam block
// (devices::BeamBlockSettings): after the point's frames, the flag swings into the source beam
// ahead of the sample and `frames` more frames at the point's exposure see everything but the
// light the sample scatters; their mean is subtracted from the point's value and its
// uncertainty enters the point's sigma (docs/measurement.md). A plan that asks for it on a bench
// without a beam block is refused.
struct BackgroundPolicy {
  bool measure = false;
  int frames = 0;  // 0: as many as the point's (ExposurePolicy::frames, at least 2)
};

struct Rectangle {
  int x = 0, y = 0, width = 0, height = 0;  // image pixels
};

// [rectangle] auto = true: the largest rectangle (of the given aspect, centred where asked) whose
// averaging over its spread of directions changes the specimen's expected lobe by at most
// `tolerance` times the expected relative sigma of a lobe point, at every planned point within
// the lobe (above a tenth of its incidence's peak). Walter 2007 section 6: "smaller for
// less-diffusing samples". Needs the bench's geometry and the specimen's expected width.
struct AutoRectangle {
  double tolerance = 0.3;
  double expected_sigma = 5e-4;  // relative, of a lobe point (the demo's budget at the peak)
  double aspect = 3;             // height / width
  std::optional<int> centre_x, centre_y;  // image pixels; default: the image's centre
};

// A plan's modes, parsed once from their names in the plan's file (the names are also what the
// database and the API show: ToString).
// Which side of the specimen the camera looks from: through the hemisphere (the bench's main use)
// or on the light side, at the rough face.
enum class Side { kTransmission, kReflection };
// What a plan's view angles are measured from: theta_v itself; the straight-through view
// (transmission, Snell at the specimen's eta); the mirror direction (reflection).
enum class ViewAbout { kNormal, kRefracted, kSpecular };
enum class StrategyKind { kUniform, kLobe, kAdaptive };
inline constexpr std::array<const char*, 2> kSideNames = {"transmission", "reflection"};
inline constexpr std::array<const char*, 3> kViewAboutNames = {"normal", "refracted", "specular"};
inline constexpr std::array<const char*, 3> kStrategyNames = {"uniform", "lobe", "adaptive"};
inline const char* ToString(Side s) { return kSideNames[static_cast<std::size_t>(s)]; }
inline const char* ToString(ViewAbout v) { return kViewAboutNames[static_cast<std::size_t>(v)]; }
inline const char* ToString(StrategyKind k) { return kStrategyNames[static_cast<std::size_t>(k)]; }

// How a run spends its bench time ([strategy] in a plan; acquisition/strategy.h).
//   uniform   every point of the grid, in order (the default);
//   lobe      the grid's points where the specimen's expected lobe (Beckmann at the catalogue's
//             width) is above `lobe_fraction` of its incidence's peak, and every `tail_every`-th
//             view outside it (the tails pin the stray-light floor);
//   adaptive  a coarse scan (every `coarse_every`-th view, `coarse_frames` frames of at most
//             `coarse_max_s`: it only has to find the lobe), then points chosen in batches (of
//             `batch`, or a quarter of the points so far when that is more)
//             from the grid where they shrink the variance of alpha the most per bench second, at
//             the provisional fit; it stops at `target_rel_sigma_alpha` or at `budget_s`.
struct StrategyPolicy {
  StrategyKind kind = StrategyKind::kUniform;
  double lobe_fraction = 0.01;
  int tail_every = 4;
  int coarse_every = 4;
  int coarse_frames = 1;
  double coarse_max_s = 1;
  int batch = 4;
  double target_rel_sigma_alpha = 0;  // sigma(alpha) / alpha to stop at; 0: none
  double budget_s = 0;                // bench seconds (exposures and moves) at most; 0: none
};

struct PlannedPoint {
  int index = 0;  // order of measurement
  double theta_l_deg = 0, theta_v_deg = 0, phi_deg = 0;
  // The camera on the light side: theta_v from +n, theta_v = theta_l specular
  // (StageTargetsForReflection). Otherwise through the hemisphere, theta_v from -n.
  bool reflection = false;
  StageTargets stage;  // sample, arm, azimuth (deg)
  bool skipped = false;
  std::string reason;  // why it is skipped
  // Points an adaptive run chose (strategy.h): the exposure planned for them (the engine's first
  // try) and the bench seconds predicted for them; nullopt and 0 for the points a plan set out.
  std::optional<double> planned_exposure_s;
  double predicted_s = 0;
};

struct Plan {
  std::string path;
  Specimen specimen;
  std::vector<double> incidence_deg, azimuth_deg;
  double view_from_deg = -80, view_to_deg = 80, view_step_deg = 2;
  Side side = Side::kTransmission;
  // kNormal: view angles are theta_v; kRefracted (transmission): offsets from the straight-through
  // view theta_v = -theta_t (Snell at the specimen's eta); kSpecular (reflection): offsets from
  // the mirror direction theta_v = theta_l. Either way each incidence sweeps its own lobe.
  ViewAbout view_about = ViewAbout::kNormal;
  double arm_shadow_half_angle_deg = 4;
  ExposurePolicy exposure;
  DarkPolicy darks;
  StrategyPolicy strategy;
  BackgroundPolicy background;
  // The instrument's beam block (PlanContext::beam_block), whether or not the plan measures
  // backgrounds: the engine keeps the flag out of the beam for the point's own frames.
  std::optional<devices::BeamBlockSettings> beam_block;
  Rectangle rectangle;
  std::optional<AutoRectangle> auto_rectangle;  // when the plan chose it: how
  std::string rectangle_reason;                 // which rectangle, and why (auto only)
  std::string text;                             // the file as read, stored with the run
};

struct PlanContext {
  std::vector<Specimen> specimens;
  std::vector<devices::AxisSettings> axes;  // travel limits
  int image_width = 0, image_height = 0;    // 0: not checked
  // What a run needs of the camera: every point records the sensor temperature, and darks need
  // the shutter. A plan for a camera without either is refused (naming what is missing).
  std::string camera_missing;  // "" when the camera has both
  // The bench's beam block ([beam_block] in the instrument config); nullopt: none, and a plan
  // with [background] measure = true is refused.
  std::optional<devices::BeamBlockSettings> beam_block;
  // The bench's optics and the camera's region (the rectangle is the plan's), for plans whose
  // rectangle is chosen by the response ([rectangle] auto); nullopt: the config has no [bench].
  std::optional<fitting::ResponseSetup> response;
};

// What rebuilds the instrument response of a run of `plan` measured through `rectangle`: the
// context's bench and camera region with the specimen's thickness; nullopt without a bench.
std::optional<fitting::ResponseSetup> ResponseSetupFor(const PlanContext& context, const Plan& plan,
                                                       const Rectangle& rectangle);

// Parses and validates; errors carry "path:line: what".
Result<Plan> LoadPlan(const std::string& path, const PlanContext& context);
// The same from text (an API request, a run's stored plan); errors carry "name:line: what".
Result<Plan> LoadPlanText(std::string_view text, const std::string& name,
                          const PlanContext& context);

// The grid in measurement order: incidence by incidence (the sample axis moves least), the view
// sweep alternating direction (a serpentine: the arm never flies back), azimuths outermost.
// Unreachable or occluded geometries come back with skipped = true and a reason.
std::vector<PlannedPoint> ExpandGrid(const Plan& plan, const PlanContext& context);
// The points a run starts with: the grid, with the points the plan's strategy leaves out (lobe:
// outside the expected lobe; adaptive: off the coarse scan, candidates for later choices)
// skipped with the strategy's reason (SelectByStrategy, strategy.h).
std::vector<PlannedPoint> ExpandPoints(const Plan& plan, const PlanContext& context);

// What an earlier run of the same specimen measured: each point's final exposure and how many
// ranging tries it took, to price a new plan's points (Storage::LatestExposures reads them).
struct ExposureHistory {
  struct Entry {
    double theta_l_deg = 0, theta_v_deg = 0, phi_deg = 0;
    double exposure_s = 0;
    int ranging_tries = 0;
    bool reflection = false;
  };
  std::int64_t run = 0;  // the run they come from
  std::vector<Entry> entries;
  // The measured geometry nearest in view angle on the same side at the same incidence and
  // azimuth (within 1 deg); nullopt where the earlier run did not measure that incidence.
  std::optional<Entry> Near(const PlannedPoint& p) const;
};

// The frames a point's background takes (0 when the plan measures none).
int BackgroundFrames(const Plan& plan);

// Seconds the stages take from one position to the next: a trapezoid per axis at its configured
// speed and acceleration, all axes together (the slowest decides); axes not in `axes`: none.
double MoveSeconds(const std::vector<devices::AxisSettings>& axes, const StageTargets& from,
                   const StageTargets& to);

struct LobeForecast;  // exposure.h

// What an estimate is made of (bench seconds and counts), for reports and tests.
struct EstimateParts {
  double motion_s = 0, exposure_s = 0;  // exposure_s: every frame, ranging tries and darks too
  double dark_exposure_s = 0;           // of which darks
  int ranging_frames = 0;               // tries beyond the first averaged frame
  int from_history = 0, from_forecast = 0, from_typical = 0;  // points priced by each
};

// Seconds of bench time the run should take: moves along the order at the axes' speeds plus, per
// point, its frames, ranging tries and the darks the engine takes at each exposure it tries
// (reused while fresh, DarkPolicy::max_age_s), and its background's frames and the beam block's
// move when the plan measures backgrounds. Each point is priced, in this order, at:
//   - the exposure and ranging tries of the nearest point of `history` (an earlier run of the
//     specimen);
//   - the engine's own ranging (JudgeExposure) played on `forecast`'s expected brightness (the
//     specimen's catalogue lobe at the bench's measured throughput), from the previous point's
//     exposure as the engine starts;
//   - `typical_exposure_s` with one ranging frame.
// Readout is not counted.
double EstimateSeconds(const Plan& plan, const std::vector<PlannedPoint>& points,
                       const std::vector<devices::AxisSettings>& axes, double typical_exposure_s,
                       const ExposureHistory* history = nullptr,
                       const LobeForecast* forecast = nullptr, EstimateParts* parts = nullptr);

}  // namespace gonio::acquisition
