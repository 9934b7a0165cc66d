#include "fitting/internal/geometry_profile.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <functional>
#include <iomanip>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "fitting/internal/fit_once.h"
#include "fitting/internal/floor_choice.h"
#include "fitting/internal/response_budget.h"
#include "fitting/internal/uncertainty.h"

namespace gonio::fitting::internal {
namespace {

// The samples with every response's setup changed by `change` (one copy per distinct setup).
template <typename Change>
std::vector<Sample> WithSetupChanged(std::span<const Sample> samples, Change change) {
  std::map<const ResponseSetup*, std::shared_ptr<const ResponseSetup>> moved;
  std::vector<Sample> out(samples.begin(), samples.end());
  for (Sample& s : out) {
    if (!s.response || !s.response->setup) continue;
    auto& m = moved[s.response->setup.get()];
    if (!m) {
      ResponseSetup c = *s.response->setup;
      change(c);
      m = std::make_shared<const ResponseSetup>(std::move(c));
    }
    s.response->setup = m;
  }
  return out;
}

// A local refit from `fit`'s solution, its floor choice kept (nullopt when it does not converge).
std::optional<FitSummary> Refit(std::span<const Sample> samples, SolveOptions o,
                                const FitSummary& fit) {
  o.floor = fit.floor_fitted ? Floor::kFit : Floor::kOff;
  o.initial_width = fit.width.value;
  o.automatic_starts = false;
  auto f = FitOnce(samples, o);
  if (!f.ok() || f->status == FitStatus::kFailed) return std::nullopt;
  return std::move(f).value();
}

// A least-squares refit of the moved samples from `fit`'s solution. Against one of the unmoved
// (from the same solution) it gives the estimator's derivative along the move: at the solution a
// robust loss weighs like least squares, and a robust refit of a setup moved by a whole pixel
// leaves residuals of many sigma, where Huber's reweighting converges linearly (hundreds of
// iterations in CI's demo) and measures the loss's response to outliers, not the derivative.
std::optional<FitSummary> MovedRefit(std::span<const Sample> moved, const SolveOptions& o,
                                     const FitSummary& fit) {
  SolveOptions ls = o;
  ls.loss = Loss::kNone;
  return Refit(moved, ls, fit);
}

// One run-wide setup quantity profiled (NuisanceUse in fitter.h): how a setup moves by d of it
// (nullopt from MovedBy where the setup refuses that, e.g. a plate of no thickness) and its
// stated sigma, in its unit.
struct Quantity {
  std::function<void(ResponseSetup&, double)> change;
  double prior = 0;
};

// The samples with every quantity k moved by d[k], or nullopt where a setup refuses the change.
std::optional<std::vector<Sample>> MovedBy(std::span<const Sample> used,
                                           const std::vector<Quantity>& q,
                                           const Eigen::VectorXd& d) {
  auto m = WithSetupChanged(used, [&q, &d](ResponseSetup& c) {
    for (std::size_t k = 0; k < q.size(); ++k)
      if (d[k] != 0) q[k].change(c, d[k]);
  });
  for (const Sample& s : m)
    if (s.response && s.response->setup && !s.response->setup->Validate().ok()) return std::nullopt;
  return m;
}

// What a joint profile gives: each quantity's use, why a quantity's data were not used, and the
// joint estimates (the posterior's most probable offsets with every quantity's data in, before
// any was dropped for lying beyond the probes; NaN for a quantity whose data did not enter).
struct JointUse {
  std::vector<NuisanceUse> use;
  std::vector<bool> left_out;  // no refit with it moved converged: its part is not in sigma
  std::vector<std::string> why_not;
  std::vector<bool> beyond;  // the data put it beyond the probes (its prior alone then)
  std::vector<bool> flat;    // chi-square not convex along it at these probes
  Eigen::VectorXd estimate;
};

// What one profile's probes give (JointProfileAt): the refit at the centre, and with
// u = (offset - at) / step, chi2(u) = C + b.u + u.Q.u and w(u) = w0 + w1.u + u.W.u; per quantity
// whether its data terms enter.
struct ProbedQuadratic {
  FitSummary centre;
  Eigen::VectorXd b, w1;
  Eigen::MatrixXd Q, W;
  std::vector<bool> data;
};

// The probes' refits and the quadratic through them (the diagonal from the single probes, the
// cross terms from the pairs where `cross`); marks each quantity probed, flat or left out in
// `out`. nullopt when the refit at `at` does not converge.
std::optional<ProbedQuadratic> ProbeAbout(std::span<const Sample> used,
                                          const std::vector<Quantity>& q, const SolveOptions& o,
                                          const FitSummary& fit, const FitSummary& base,
                                          const Eigen::VectorXd& at, const Eigen::VectorXd& step,
                                          bool cross, const std::vector<bool>& excluded,
                                          JointUse& out) {
  const int n = static_cast<int>(q.size());
  auto refit = [&](const Eigen::VectorXd& d) -> std::optional<FitSummary> {
    auto m = MovedBy(used, q, d);
    if (!m) return std::nullopt;
    std::ostringstream t;
    t << "the geometry's profile: a refit with its setup moved by (" << d.transpose() << ")";
    ReportProgress(o, t.str());
    return MovedRefit(*m, o, fit);
  };
  std::optional<FitSummary> centre = at.isZero() ? std::optional<FitSummary>(base) : refit(at);
  if (!centre) return std::nullopt;
  std::vector<std::optional<FitSummary>> up(n), down(n);
  for (int k = 0; k < n; ++k) {
    Eigen::VectorXd e = Eigen::VectorXd::Zero(n);
    e[k] = step[k];
    up[k] = refit(at + e);
    down[k] = refit(at - e);
  }
  ProbedQuadratic d{*centre,
                    Eigen::VectorXd::Zero(n),
                    Eigen::VectorXd::Zero(n),
                    Eigen::MatrixXd::Zero(n, n),
                    Eigen::MatrixXd::Zero(n, n),
                    std::vector<bool>(n, false)};
  for (int k = 0; k < n; ++k) {
    if (up[k] && down[k]) {
      out.use[k].probed = true;
      d.b[k] = (up[k]->chi2 - down[k]->chi2) / 2;
      d.Q(k, k) = (up[k]->chi2 + down[k]->chi2) / 2 - centre->chi2;
      d.w1[k] = (up[k]->width.value - down[k]->width.value) / 2;
      d.W(k, k) = (up[k]->width.value + down[k]->width.value) / 2 - centre->width.value;
      d.data[k] = d.Q(k, k) > 0 && !excluded[k];
      out.flat[k] = !(d.Q(k, k) > 0);
      if (out.flat[k]) out.why_not[k] = "chi-square not convex along it";
    } else if (up[k] || down[k]) {  // one way only: linear in it
      const std::optional<FitSummary>& one = up[k] ? up[k] : down[k];
      d.w1[k] = (one->width.value - centre->width.value) * (up[k] ? 1 : -1);
    } else {
      out.left_out[k] = true;
    }
  }
  for (int i = 0; i < n; ++i)
    for (int j = i + 1; j < n; ++j) {
      if (!cross || !d.data[i] || !d.data[j]) continue;
      Eigen::VectorXd e = Eigen::VectorXd::Zero(n);
      e[i] = step[i];
      e[j] = step[j];
      auto both = refit(at + e);
      if (!both) continue;  // no cross term: the pair is taken as independent
      d.Q(i, j) = d.Q(j, i) =
          (both->chi2 - centre->chi2 - d.b[i] - d.b[j] - d.Q(i, i) - d.Q(j, j)) / 2;
      d.W(i, j) = d.W(j, i) =
          (both->width.value - centre->width.value - d.w1[i] - d.w1[j] - d.W(i, i) - d.W(j, j)) / 2;
    }
  return d;
}

// The offsets' posterior in steps, N(mu, S), from the data terms of the quantities whose data
// enter and the priors: solved, then solved again without a quantity whose data put it beyond
// 1.5 steps (or make the quadratic indefinite), until none does. Sets `data` to the quantities
// whose data stayed in, and in `out` why the others' did not, which lay beyond, and the joint
// estimates of the first solve.
void SolvePosterior(const ProbedQuadratic& d, const FitSummary& base,
                    const Eigen::VectorXd& prior_u, const Eigen::VectorXd& at,
                    const Eigen::VectorXd& step, std::vector<bool>& data, Eigen::VectorXd& mu,
                    Eigen::MatrixXd& S, JointUse& out) {
  const int n = static_cast<int>(data.size());
  const Eigen::VectorXd at_u = at.cwiseQuotient(step);
  bool first_solve = true;
  for (;;) {
    Eigen::MatrixXd Qd = d.Q;
    Eigen::VectorXd bd = d.b;
    int m = 0;
    for (int k = 0; k < n; ++k) {
      if (data[k]) {
        ++m;
        continue;
      }
      Qd.row(k).setZero();
      Qd.col(k).setZero();
      bd[k] = 0;
    }
    // Chi-square's scale: the reduced chi-square at the data's minimum, with the quantities
    // counted as parameters (not the unmoved refit's: a quantity far from its stated value
    // inflates that by the very misfit it explains, which flattened the quadratic).
    double chi2_min = base.chi2;
    Eigen::LDLT<Eigen::MatrixXd> data_only(Qd);
    if (m > 0 && data_only.info() == Eigen::Success && data_only.isPositive()) {
      Eigen::MatrixXd Qm = Qd;
      for (int k = 0; k < n; ++k)
        if (!data[k]) Qm(k, k) = 1;  // a placeholder that leaves the others' minimum alone
      Eigen::LLT<Eigen::MatrixXd> llt(Qm);
      if (llt.info() == Eigen::Success) chi2_min = d.centre.chi2 - bd.dot(llt.solve(bd)) / 4;
    }
    const double dof = base.n_points - base.n_params - m;
    const double inflate = dof > 0 ? std::max(1.0, chi2_min / dof) : 1.0;
    Eigen::MatrixXd M = Qd / inflate;
    Eigen::VectorXd g = bd / inflate;
    for (int k = 0; k < n; ++k) {
      M(k, k) += 1 / (prior_u[k] * prior_u[k]);
      g[k] += 2 * at_u[k] / (prior_u[k] * prior_u[k]);
    }
    Eigen::LLT<Eigen::MatrixXd> llt(M);
    int drop = -1;
    if (llt.info() != Eigen::Success) {  // not a minimum: the largest data term goes
      for (int k = 0; k < n; ++k)
        if (data[k] && (drop < 0 || d.Q(k, k) > d.Q(drop, drop))) drop = k;
      out.why_not[drop] = "chi-square not convex along it";
    } else {
      S = llt.solve(Eigen::MatrixXd::Identity(n, n));
      mu = -S * g / 2;
      if (first_solve)  // the joint estimates, before any quantity's data are dropped
        for (int k = 0; k < n; ++k)
          if (data[k]) out.estimate[k] = at[k] + mu[k] * step[k];
      first_solve = false;
      for (int k = 0; k < n; ++k)
        if (data[k] && std::abs(mu[k]) > 1.5 && (drop < 0 || std::abs(mu[k]) > std::abs(mu[drop])))
          drop = k;
      if (drop >= 0) {
        std::ostringstream w;
        w << std::setprecision(2) << "the data put it " << at[drop] + mu[drop] * step[drop]
          << " off, beyond the probes: check the stated value";
        out.why_not[drop] = w.str();
        out.beyond[drop] = true;
      }
    }
    if (drop < 0) break;
    data[drop] = false;
  }
}

// The quantities profiled together, about `at` with probes at +-`step` (both vectors in their
// units): least-squares refits from `fit`'s solution at `at`, at each one moved a step either
// way, and at each pair moved a step up together. With u = (offset - at) / step they give
// chi2(u) = C + b.u + u.Q.u and w(u) = w0 + w1.u + u.W.u (Q, W symmetric: the diagonal from the
// single probes, the cross terms from the pairs); the priors add sum_k ((at_k + u_k step_k) /
// prior_k)^2, so the offsets' posterior is N(at + step mu, step S step) with S^-1 = Q + diag(
// (step / prior)^2) and mu = -S (b + 2 at step / prior^2) / 2 (chi-square as -2 ln L, scaled by
// the reduced chi-square at its minimum where that exceeds 1, as the parameters' sigmas are). The
// width moves to w(mu), with variance g.S.g + 2 tr((W S)^2), g = w1 + 2 W mu (a Gaussian
// through a quadratic). Profiled one at a time, quantities that move the lobe alike (the
// thickness and the rectangle's x both shift a sweep) each took the whole shift, and the fit
// moved to both: on antiglare the thickness went 5 sigma and x 3 sigma off to absorb one
// sample-stage error, and the stage's offsets came out of the wrong sign. The data's quadratic
// is only trusted inside the probed range: a quantity whose mu lies beyond 1.5 steps, or along
// which chi-square is not convex, keeps its prior alone (its data terms dropped, which leaves it
// independent of the others; the note says why), as does a quantity probed one way only, which
// is then linear in it. nullopt when the refit at `at` does not converge.
std::optional<JointUse> JointProfileAt(std::span<const Sample> used, const std::vector<Quantity>& q,
                                       const SolveOptions& o, const FitSummary& fit,
                                       const FitSummary& base, const Eigen::VectorXd& at,
                                       const Eigen::VectorXd& step, bool cross,
                                       const std::vector<bool>& excluded) {
  const int n = static_cast<int>(q.size());
  JointUse out;
  out.use.assign(n, NuisanceUse{});
  out.why_not.assign(n, "");
  out.left_out.assign(n, false);
  out.beyond.assign(n, false);
  out.flat.assign(n, false);
  out.estimate = Eigen::VectorXd::Constant(n, std::numeric_limits<double>::quiet_NaN());
  const auto d = ProbeAbout(used, q, o, fit, base, at, step, cross, excluded, out);
  if (!d) return std::nullopt;
  Eigen::VectorXd prior_u(n);  // the priors' sigma in steps
  for (int k = 0; k < n; ++k) prior_u[k] = q[k].prior / step[k];
  std::vector<bool> data = d->data;
  Eigen::VectorXd mu(n);
  Eigen::MatrixXd S(n, n);
  SolvePosterior(*d, base, prior_u, at, step, data, mu, S, out);
  // The width: its shift at mu, and its variance, split among the quantities by their shares
  // g_k (S g)_k + 2 ((W S)^2)_kk of the whole (negative shares, from anticorrelated quantities,
  // count 0; the split is rescaled to the whole).
  const Eigen::VectorXd g = d->w1 + 2 * d->W * mu;
  const Eigen::MatrixXd WS = d->W * S, WS2 = WS * WS;
  const double total = std::max(0.0, g.dot(S * g) + 2 * WS2.trace());
  const double shift = d->centre.width.value - base.width.value + d->w1.dot(mu) + mu.dot(d->W * mu);
  const Eigen::VectorXd Sg = S * g;
  Eigen::VectorXd share(n), part(n);
  for (int k = 0; k < n; ++k) {
    share[k] = std::max(0.0, g[k] * Sg[k] + 2 * WS2(k, k));
    part[k] = std::abs(d->w1[k] * mu[k] + d->W(k, k) * mu[k] * mu[k]);
  }
  const double share_sum = share.sum(), part_sum = part.sum();
  for (int k = 0; k < n; ++k) {
    NuisanceUse& u = out.use[k];
    u.fitted = data[k];
    u.offset = at[k] + mu[k] * step[k];
    u.offset_sigma = std::sqrt(S(k, k)) * step[k];
    u.width_sigma = share_sum > 0 ? std::sqrt(total * share[k] / share_sum) : 0.0;
    u.width_shift = part_sum > 0 ? shift * part[k] / part_sum : shift / n;
  }
  return out;
}

// Profiles about the stated values with probes at their sigmas, each quantity alone (no cross
// terms), then again, with the cross terms, about the offsets found, with probes at twice their
// sigmas where the data know a quantity to better than a quarter of the first step: the slope of
// chi-square through probes far outside the posterior carries their cubic terms (on the demo's
// joint fit one-pixel probes put the rectangle 0.007 px from where probes at 0.01 px do, more than
// its sigma of 0.005 px; on antiglare, 0.045 px against 0.0035), while its curvature does not
// change from 1 to 0.01 px; cross terms from a pair of such probes were worse still. The first
// profile only scouts where more than one quantity is stated: alone, each takes what the others
// explain (on antiglare x landed nine of the second probes' steps from the joint estimate, and a
// thickness 0.4 mm off looked 1.5 mm off beside a rectangle 0.5 px off). Where the second probes
// put an offset beyond themselves, they are taken again about the joint estimates (Newton's
// iteration on the data's quadratic), up to four times; a quantity whose estimate lies beyond 1.5
// of its prior's sigma keeps its prior (the note says to check the stated value). Should they not
// settle, the last profile stands, the quantities beyond its probes at their priors.
std::optional<JointUse> JointProfile(std::span<const Sample> used, const std::vector<Quantity>& q,
                                     const SolveOptions& o, const FitSummary& fit,
                                     const FitSummary& base) {
  const int n = static_cast<int>(q.size());
  Eigen::VectorXd prior(n);
  for (int k = 0; k < n; ++k) prior[k] = q[k].prior;
  std::vector<bool> excluded(n, false);
  auto first =
      JointProfileAt(used, q, o, fit, base, Eigen::VectorXd::Zero(n), prior, false, excluded);
  if (!first) return first;
  Eigen::VectorXd centre(n), step(n);
  bool finer = false;
  int with_data = 0;  // fitted, or beyond the first probes
  for (int k = 0; k < n; ++k) {
    const NuisanceUse& u = first->use[k];
    const bool sharp = u.fitted && u.offset_sigma < prior[k] / 4;
    finer = finer || sharp;
    with_data += u.fitted || first->beyond[k];
    centre[k] = u.fitted ? u.offset : 0;
    step[k] = sharp ? 2 * u.offset_sigma : prior[k];
  }
  if (with_data < 2) {  // one quantity: its own profile, refined where sharp
    for (int k = 0; k < n; ++k) excluded[k] = !first->use[k].fitted;
    if (!finer) return first;
  }
  std::optional<JointUse> last;
  std::vector<std::string> named(n);  // why an excluded quantity keeps its prior
  auto done = [&named, &excluded](JointUse& u) {
    for (std::size_t k = 0; k < named.size(); ++k)
      if (excluded[k] && !named[k].empty()) u.why_not[k] = named[k];
    return std::optional<JointUse>(std::move(u));
  };
  for (int round = 0; round < 5; ++round) {
    auto again = JointProfileAt(used, q, o, fit, base, centre, step, true, excluded);
    if (!again) break;
    bool moved = false;
    for (int k = 0; k < n; ++k) {
      if (!again->beyond[k]) continue;
      if (std::abs(again->estimate[k]) > 1.5 * prior[k]) {
        excluded[k] = true;  // far from the stated value: named, not followed, held there
        named[k] = again->why_not[k];
        centre[k] = 0;
      } else {
        moved = true;
      }
    }
    // A quantity the predictions depend on through its square (the rectangle across the plane of
    // incidence: chi-square quartic about 0) is convex at the first probes and flat at finer
    // ones: it goes back to the first probes' step.
    for (int k = 0; k < n; ++k)
      if (again->flat[k] && first->use[k].fitted && step[k] < prior[k]) {
        step[k] = prior[k];
        centre[k] = first->use[k].offset;
        moved = true;
      }
    bool newly_excluded = false;
    for (int k = 0; k < n; ++k)
      newly_excluded = newly_excluded || (again->beyond[k] && excluded[k]);
    last = std::move(again);
    if (!moved && !newly_excluded) return done(*last);
    if (!moved) continue;  // again without the far ones
    for (int k = 0; k < n; ++k)
      if (!excluded[k] && std::isfinite(last->estimate[k])) centre[k] = last->estimate[k];
  }
  return last ? done(*last) : first;
}

// "x +0.12 +- 0.31 px (from the data; prior 1)"
std::string DescribeNuisance(const NuisanceUse& n, const char* unit, double prior,
                             const std::string& why_not) {
  std::ostringstream d;
  d << std::setprecision(2);
  if (n.fitted)
    d << std::showpos << n.offset << std::noshowpos << " +- " << n.offset_sigma << " " << unit
      << " from the data (stated +-" << prior << "): width " << std::showpos << n.width_shift
      << std::noshowpos << " +- " << n.width_sigma;
  else
    d << "+-" << prior << " " << unit << " as stated"
      << (why_not.empty() ? std::string() : " (" + why_not + ")") << ": width +-" << n.width_sigma;
  return d.str();
}

// The nuisance parameters the data fixed, each counted as 1 - s^2 / sigma_prior^2 of a parameter
// (the share of its prior the data replaced; 0 where the prior stands), in the degrees of freedom
// of chi2/dof, the poor-fit test and the information criteria. Without it a fit whose geometry the
// data found looked better than it is: on 17 points with 3 parameters, up to 20 % below its
// chi2/dof. Where chi2/dof inflated the sigmas (least squares), they follow the new value.
void CountNuisance(const GeometryUse& g, const BenchOptics& b, const FitOptions& o,
                   FitSummary& fit) {
  auto share = [](const NuisanceUse& n, double prior) {
    if (!n.fitted || !(prior > 0)) return 0.0;
    return std::clamp(1 - (n.offset_sigma * n.offset_sigma) / (prior * prior), 0.0, 1.0);
  };
  const double nu = share(g.thickness, b.thickness_sigma_mm) +
                    share(g.rectangle_x, b.rectangle_sigma_px) +
                    share(g.rectangle_y, b.rectangle_sigma_px);
  // At least one degree of freedom stays (ValidateSamples asks for n_params + 1 samples).
  const double n_nuisance = std::min(nu, std::max(0.0, fit.n_points - fit.n_params - 1.0));
  if (n_nuisance <= 0) return;
  const double before = fit.reduced_chi2;
  fit.n_nuisance = n_nuisance;
  SetInformation(fit);
  if (o.inflate_by_reduced_chi2 && o.loss == Loss::kNone) {
    const double r = std::sqrt(std::max(1.0, fit.reduced_chi2) / std::max(1.0, before));
    for (Parameter* q : {&fit.width, &fit.scale, &fit.eta, &fit.floor}) q->sigma *= r;
  }
  if (fit.status != FitStatus::kFailed) JudgeFit(fit.width.sigma > 0, fit);
}

// The angle read-back (GeometryUse): the arm's per point, through each sample's sigma; the sample
// stage's per group of points taken without moving it, as an offset of the solve (StageGroups),
// the fit redone with both where they matter. Sets `so` to the options the later refits take
// (with the groups where they went in) and `widened` to the samples with the arm's term in their
// sigmas; returns the angle's share of the width's sigma.
Result<double> AngleReadBack(std::span<const Sample> samples, const FitOptions& o,
                             const BenchOptics& b, FitSummary& fit, GeometryUse& g,
                             std::ostringstream& note, SolveOptions& so,
                             std::vector<Sample>& widened) {
  if (!(b.angle_sigma_deg > 0)) {
    note << "angle read-back: not stated";
    return 0.0;
  }
  double angle_part = 0;
  const double a_sigma = b.angle_sigma_deg;
  auto stage = std::make_shared<StageGroups>();
  stage->prior_deg = a_sigma;
  stage->group.assign(samples.size(), -1);
  stage->slope.assign(samples.size(), 0.0);
  widened.assign(samples.begin(), samples.end());
  for (std::size_t i = 0; i < widened.size(); ++i) {
    Sample& s = widened[i];
    if (!s.response || !s.response->setup) continue;
    const auto [d_sample, d_arm] = StageSlopes(fit, s);
    g.angle_max_fraction =
        std::max(g.angle_max_fraction, a_sigma * std::hypot(d_sample, d_arm) / s.sigma);
    s.sigma = std::hypot(s.sigma, a_sigma * d_arm);
    const double at = s.response->at.sample_deg;
    if (i == 0 || stage->group[i - 1] < 0 || stage->groups.back().sample_deg != at)
      stage->groups.push_back({at, 0, 0, a_sigma});
    ++stage->groups.back().points;
    stage->group[i] = static_cast<int>(stage->groups.size()) - 1;
    stage->slope[i] = d_sample;
  }
  const double tol = o.response_tolerance;
  const double adds = std::hypot(1.0, g.angle_max_fraction) - 1;
  note << std::setprecision(2) << "angle read-back +-" << b.angle_sigma_deg << " deg: at most "
       << 100 * g.angle_max_fraction << " % of a sample's sigma (adding " << 100 * adds
       << " % in quadrature)";
  if (!(adds > tol * tol / 2)) {
    note << ", left out (the fit takes it in above " << 100 * tol * tol / 2 << " %)";
    return 0.0;
  }
  SolveOptions with_stage(o);
  with_stage.stage = stage;
  auto again = FitWithFloor(widened, with_stage);
  if (!again.ok()) return again.error();
  if (again->status == FitStatus::kFailed) return 0.0;
  const std::string floor_choice = fit.floor_choice;
  fit = std::move(again).value();
  if (fit.floor_choice.empty()) fit.floor_choice = floor_choice;
  g.angle_in_fit = true;
  so = with_stage;
  // Its share of the width's sigma: the sigma with and without it, both uninflated by
  // chi-square (the fit without it may have been inflated by the very scatter it explains).
  SolveOptions plain = so, plain_without(o);
  plain.inflate_by_reduced_chi2 = plain_without.inflate_by_reduced_chi2 = false;
  const auto with = Refit(widened, plain, fit), without = Refit(samples, plain_without, fit);
  if (with && without)
    angle_part = std::sqrt(std::max(
        0.0, with->width.sigma * with->width.sigma - without->width.sigma * without->width.sigma));
  note << ", in the fit: the arm's in each sample's sigma, the sample stage's as one offset "
          "for each of "
       << stage->groups.size() << " groups of points taken without moving it";
  return angle_part;
}

// Common to the run: the thickness and the rectangle's position, profiled together as nuisance
// parameters (JointProfile) by refits of the samples the fit used, `used` (with the angle term in
// their sigmas where it went in). One that does not converge leaves its part out of sigma, and
// the note says so; the fit itself stands. Returns the width's shift at the geometry found.
double ProfileThicknessAndRectangle(std::span<const Sample> used, const SolveOptions& so,
                                    const BenchOptics& b, const FitSummary& fit, GeometryUse& g,
                                    std::ostringstream& note) {
  std::optional<FitSummary> base;
  if (b.thickness_sigma_mm > 0 || b.rectangle_sigma_px > 0) {
    SolveOptions ls = so;
    ls.loss = Loss::kNone;
    base = Refit(used, ls, fit);
  }
  const char* why = base ? " (a refit with it moved did not converge)"
                         : " (the unmoved least-squares refit did not converge)";
  // The quantities stated: the thickness, and the rectangle's x and y (d output pixels along an
  // axis is the optical axis as far the other way).
  std::vector<Quantity> q;
  int k_thickness = -1, k_x = -1;
  if (b.thickness_sigma_mm > 0) {
    k_thickness = static_cast<int>(q.size());
    q.push_back({[](ResponseSetup& c, double d) { c.thickness_mm += d; }, b.thickness_sigma_mm});
  }
  if (b.rectangle_sigma_px > 0) {
    k_x = static_cast<int>(q.size());
    q.push_back({[](ResponseSetup& c, double d) { c.bench.axis_x_px -= d * c.rectangle.binning_h; },
                 b.rectangle_sigma_px});
    q.push_back({[](ResponseSetup& c, double d) { c.bench.axis_y_px -= d * c.rectangle.binning_v; },
                 b.rectangle_sigma_px});
  }
  std::optional<JointUse> joint;
  if (base && !q.empty()) joint = JointProfile(used, q, so, fit, *base);
  double shift = 0;
  if (k_thickness >= 0) {
    const double t = b.thickness_sigma_mm;
    if (joint && !joint->left_out[k_thickness]) {
      const NuisanceUse& n = joint->use[k_thickness];
      g.thickness = n;
      g.width_thickness = n.width_sigma;
      shift += n.width_shift;
      note << "; thickness " << DescribeNuisance(n, "mm", t, joint->why_not[k_thickness]);
    } else {
      g.left_out = true;
      note << "; thickness +-" << t << " mm: LEFT OUT of sigma" << why;
    }
  } else {
    note << "; thickness: not stated";
  }
  if (k_x >= 0) {
    const double p = b.rectangle_sigma_px;
    if (joint && !joint->left_out[k_x] && !joint->left_out[k_x + 1]) {
      g.rectangle_x = joint->use[k_x];
      g.rectangle_y = joint->use[k_x + 1];
      g.width_rectangle = std::hypot(g.rectangle_x.width_sigma, g.rectangle_y.width_sigma);
      shift += g.rectangle_x.width_shift + g.rectangle_y.width_shift;
      note << "; rectangle x " << DescribeNuisance(g.rectangle_x, "px", p, joint->why_not[k_x])
           << ", y " << DescribeNuisance(g.rectangle_y, "px", p, joint->why_not[k_x + 1]);
    } else {
      g.left_out = true;
      note << "; rectangle +-" << p << " px: LEFT OUT of sigma" << why;
    }
  } else {
    note << "; rectangle position: not stated";
  }
  return shift;
}

// The fit at the most probable geometry, with the fit's own loss, from its solution: the width,
// k, the floor, chi-square and the residuals are then all of the geometry the data found
// (Predict models it too). Should that refit not converge, the width alone moves by the
// profile's `shift` and the note says so.
void RefitAtGeometryFound(std::span<const Sample> used, const SolveOptions& so,
                          const GeometryUse& g, double shift, FitSummary& fit,
                          std::ostringstream& note) {
  if (!(g.thickness.fitted || g.rectangle_x.fitted || g.rectangle_y.fitted)) return;
  auto best =
      Refit(WithSetupChanged(used, [&g](ResponseSetup& c) { MoveToFitted(g, c); }), so, fit);
  if (!best) {
    fit.width.value += shift;
    note << "; the refit at that geometry did not converge: the width moved by " << std::showpos
         << shift << std::noshowpos << " alone";
    return;
  }
  const std::string floor_choice = fit.floor_choice;
  const double floor_shift = fit.floor_width_shift, floor_part = fit.width.sigma_floor;
  fit = std::move(best).value();
  if (fit.floor_choice.empty()) fit.floor_choice = floor_choice;
  // The refit keeps the floor's choice but not what the choice put in sigma.
  fit.floor_width_shift = floor_shift;
  fit.width.sigma_floor = floor_part;
  fit.width.sigma = std::hypot(fit.width.sigma, floor_part);
  note << "; refitted at that geometry";
}

}  // namespace

Result<FitSummary> WithGeometry(std::span<const Sample> samples, const FitOptions& o,
                                FitSummary fit) {
  const Sample* known = nullptr;
  for (const Sample& s : samples)
    if (s.response && s.response->setup) known = &s;
  if (fit.status == FitStatus::kFailed) return fit;
  if (known == nullptr || !o.use_response) {
    fit.geometry.note =
        "the samples carry no instrument response: the geometry's uncertainty "
        "(angles, thickness, rectangle) is not known and not in sigma";
    return fit;
  }
  const BenchOptics& b = known->response->setup->bench;
  ReportProgress(o,
                 "the geometry's uncertainty: refits with the angles, the thickness and the "
                 "rectangle as stated and moved");
  GeometryUse g;
  g.stated = true;
  std::ostringstream note;
  SolveOptions so(o);
  std::vector<Sample> widened;
  auto angle_part = AngleReadBack(samples, o, b, fit, g, note, so, widened);
  if (!angle_part.ok()) return angle_part.error();
  if (!WidthConstrained(fit) && (b.thickness_sigma_mm > 0 || b.rectangle_sigma_px > 0)) {
    // Refits with the response each (most of such a fit's time) for a width the data do not
    // constrain: not worth it. A poor fit keeps them: a geometry that is off is one reason a
    // fit is poor.
    note << "; thickness and rectangle: not computed (the data do not constrain the width)";
    g.note = note.str();
    g.sample_stage = fit.geometry.sample_stage;
    fit.width.sigma_geometry = *angle_part;
    fit.geometry = g;
    return fit;
  }
  const std::span<const Sample> used = g.angle_in_fit ? std::span<const Sample>(widened) : samples;
  const double shift = ProfileThicknessAndRectangle(used, so, b, fit, g, note);
  RefitAtGeometryFound(used, so, g, shift, fit, note);
  // The sample stage's offsets of the final fit (the one at the geometry found, where it moved).
  if (g.angle_in_fit) {
    double largest = 0;  // in the prior's sigma
    for (const StageOffset& so_g : fit.geometry.sample_stage)
      largest = std::max(largest, std::abs(so_g.offset_deg) / b.angle_sigma_deg);
    note << std::setprecision(2) << "; the sample stage's largest offset found: " << largest
         << " of its prior's sigma";
  }
  CountNuisance(g, b, o, fit);
  if (fit.n_nuisance > 0)
    note << std::setprecision(2) << "; chi2/dof counts " << fit.n_nuisance
         << " of them as fitted parameters";
  const double common = std::hypot(g.width_thickness, g.width_rectangle);
  fit.width.sigma = std::hypot(fit.width.sigma, common);
  fit.width.sigma_geometry = std::hypot(*angle_part, common);
  g.note = note.str();
  g.sample_stage = fit.geometry.sample_stage;
  fit.geometry = g;
  return fit;
}

}  // namespace gonio::fitting::internal
