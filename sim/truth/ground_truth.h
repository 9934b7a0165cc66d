// The sample's ground truth behind one interface (the scene reads it; sim/truth/ fills it):
// the BTDF*cos the bench would measure, S/k = f_t(l, v) |cos theta_l|, from an analytic
// single-scattering model or a Monte Carlo table. ChooseGroundTruth picks the cheapest one whose
// error is below the measurement noise ("model no more than the scene needs") and says why.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "sim/truth/btdf_table.h"
#include "sim/truth/compare.h"
#include "sim/truth/monte_carlo.h"

namespace gonio::sim {

class GroundTruth {
 public:
  virtual ~GroundTruth() = default;
  virtual std::string Name() const = 0;
  // f_t(l, v) |cos theta_l| for light l above and view v below (optics conventions).
  virtual double BtdfCos(const optics::Vec3<double>& l, const optics::Vec3<double>& v) const = 0;
  // f_r(l, v) |cos theta_l| for light and view both above (a camera on the light side); nullopt
  // when the truth holds transmission only (a Monte Carlo table bins the reflected flux as a
  // total, not by direction).
  virtual std::optional<double> BrdfCos(const optics::Vec3<double>& /*l*/,
                                        const optics::Vec3<double>& /*v*/) const {
    return std::nullopt;
  }
};

// An analytic model (microseconds per evaluation).
class AnalyticTruth final : public GroundTruth {
 public:
  // `brdf` (the same signature, light and view above) may be empty: transmission only.
  AnalyticTruth(std::string name, BtdfFunction f, BtdfFunction brdf = {})
      : name_(std::move(name)), f_(std::move(f)), brdf_(std::move(brdf)) {}
  std::string Name() const override { return name_; }
  double BtdfCos(const optics::Vec3<double>& l, const optics::Vec3<double>& v) const override {
    return f_(l, v) * std::abs(l.z);
  }
  std::optional<double> BrdfCos(const optics::Vec3<double>& l,
                                const optics::Vec3<double>& v) const override {
    if (!brdf_) return std::nullopt;
    return brdf_(l, v) * std::abs(l.z);
  }

 private:
  std::string name_;
  BtdfFunction f_, brdf_;
};

// A Monte Carlo table, for its own incidence only. The rectangle's pixels (near the pole) see
// light within half a degree of the nominal direction; the scene renders the whole 100 mm plate,
// whose corners are 6.6 degrees off as seen from the source 610 mm away. Light within
// kTableLightToleranceDeg reads the table at its own incidence (an approximation only for pixels
// far from any rectangle). Light further away is a caller's bug (a table is per incidence; build
// one per incidence of the plan) and aborts.
inline constexpr double kTableLightToleranceDeg = 7.0;
class TabulatedTruth final : public GroundTruth {
 public:
  TabulatedTruth(std::string name, BtdfTable table)
      : name_(std::move(name)), t_(std::move(table)) {}
  std::string Name() const override { return name_; }
  double BtdfCos(const optics::Vec3<double>& l, const optics::Vec3<double>& v) const override;
  const BtdfTable& table() const { return t_; }

 private:
  std::string name_;
  BtdfTable t_;
};

// A microfacet model of the optics library (Walter 2007 eq. 21, and eq. 20 for a reflection
// plan's BRDF), the fitter's own formulas: the cheapest truth, exact for what the fitter assumes.
// alpha is the distribution's width, eta the glass index relative to the air. Family: "beckmann" or
// "ggx"; others abort (a caller's bug: the config parser validates names).
std::shared_ptr<GroundTruth> MicrofacetTruth(const std::string& family, double alpha, double eta);

enum class TruthKind { kAnalytic, kStatisticalMonteCarlo, kExplicitSurfaces };

struct GroundTruthChoice {
  TruthKind kind = TruthKind::kAnalytic;
  std::string reason;
  double analytic_error_l1 = 0;  // Walter single scattering vs the statistical probe, noise removed
};

// Decides for a sample of smoothness s at one incidence, given the measurement's noise as a
// relative L1 over the transmitted lobe (e.g. 0.02). A short statistical Monte Carlo probe
// (~0.1 s) measures the single-scattering error; below s = 2 the explicit surfaces are chosen,
// because Smith's uncorrelated statistics themselves then differ from real surfaces by more than
// a measurement's noise (docs/ground_truth.md, failure map).
GroundTruthChoice ChooseGroundTruth(double s, double n_above, double n_below, double theta_i_deg,
                                    double noise_l1);

}  // namespace gonio::sim
