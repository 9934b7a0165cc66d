#include "fitting/internal/uncertainty.h"

#include <ceres/crs_matrix.h>
#include <ceres/problem.h>

#include <Eigen/Dense>
#include <algorithm>
#include <boost/math/special_functions/gamma.hpp>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <string>
#include <vector>

namespace gonio::fitting::internal {
namespace {

// Covariance of the solver parameters, (J^T J)^-1 from one Jacobian evaluation at the solution
// (with the robust loss's correction when there is one, as ceres::Covariance would). Returns
// false when J^T J is singular to working precision: some direction is not constrained.
bool Covariance(ceres::Problem& problem, std::vector<double*> blocks, Eigen::MatrixXd* cov,
                ceres::CRSMatrix* jacobian = nullptr) {
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = blocks;
  ceres::CRSMatrix local;
  ceres::CRSMatrix& j = jacobian ? *jacobian : local;
  if (!problem.Evaluate(eo, nullptr, nullptr, nullptr, &j)) return false;
  const int p = j.num_cols;
  Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(p, p);
  for (int r = 0; r < j.num_rows; ++r)
    for (int a = j.rows[r]; a < j.rows[r + 1]; ++a)
      for (int b = j.rows[r]; b < j.rows[r + 1]; ++b)
        jtj(j.cols[a], j.cols[b]) += j.values[a] * j.values[b];
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(jtj);
  if (es.info() != Eigen::Success) return false;
  const Eigen::VectorXd ev = es.eigenvalues();  // ascending
  if (!(ev(p - 1) > 0) || !(ev(0) > 1e-14 * ev(p - 1))) return false;
  *cov = es.eigenvectors() * ev.cwiseInverse().asDiagonal() * es.eigenvectors().transpose();
  return true;
}

// Why the data do not constrain the width, or "" where they do: a singular covariance, fewer than
// 3 samples inside the fitted lobe's half maximum, or a relative sigma above 50 %.
std::string ConstraintProblem(bool cov_ok, const FitSummary& out) {
  std::ostringstream why;
  if (!cov_ok)
    why << "the covariance is singular: the data do not constrain every parameter";
  else if (out.points_in_lobe < 3)
    why << "only " << out.points_in_lobe
        << " sample(s) lie inside the fitted lobe's half maximum: sample the peak more finely "
           "to determine the width";
  else if (out.width.sigma > 0.5 * out.width.value)
    why << "the width's relative uncertainty is " << 100 * out.width.sigma / out.width.value
        << " %: the data barely constrain it";
  return why.str();
}

}  // namespace

void SetInformation(FitSummary& out) {
  const double p = out.n_params + out.n_nuisance;
  out.reduced_chi2 = out.chi2 / (out.n_points - p);
  out.aic = out.chi2 + 2.0 * p;
  out.bic = out.chi2 + p * std::log(double(out.n_points));
}

void FillStatistics(const Problem& p, const FitOptions& o, const LocalFit& f, FitSummary& out) {
  std::vector<double> predicted = Predictions(p, o, out, f.delta, f.dark_z);
  out.residuals.clear();
  out.residuals.reserve(p.samples.size());
  out.chi2 = 0;
  for (std::size_t i = 0; i < p.samples.size(); ++i) {
    const double r = (predicted[i] - p.samples[i].value) / p.samples[i].sigma;
    out.residuals.push_back(r);
    out.chi2 += r * r;
  }
  for (int g = 0; g < p.Groups(); ++g) out.chi2 += std::pow(f.delta[g] / p.stage->prior_deg, 2);
  for (int d = 0; d < p.Sets(); ++d) out.chi2 += f.dark_z[d] * f.dark_z[d];
  SetInformation(out);
  // The lobe is judged on the surface's model, without the floor, the stage's offsets or the
  // dark sets'.
  for (std::size_t i = 0; i < p.samples.size(); ++i)
    predicted[i] -=
        out.floor.value + p.SlopeOf(i) * f.delta[p.DeltaOf(i)] + p.DarkOf(i) * f.dark_z[p.SetOf(i)];
  out.points_in_lobe = PointsInLobe(p.samples, predicted);
}

bool FillUncertainties(LocalFit& winner, const Problem& p, const FitOptions& o, FitSummary& out) {
  std::vector<double*> blocks = {winner.x + 0, winner.x + 1};
  if (o.fit_eta) blocks.push_back(winner.x + 2);
  if (p.fit_floor) blocks.push_back(winner.x + 3);
  // The stage's offsets last: the parameters' covariance is then the marginal one, over them.
  const int first_delta = static_cast<int>(blocks.size());
  for (int g = 0; g < p.Groups(); ++g) blocks.push_back(&winner.delta[g]);
  for (int d = 0; d < p.Sets(); ++d) blocks.push_back(&winner.dark_z[d]);  // marginal over them too
  Eigen::MatrixXd c;
  ceres::CRSMatrix j;
  bool cov_ok = Covariance(*winner.problem, blocks, &c, &j);
  // Inflate when the residuals scatter more than the sigmas say. With a robust loss the outliers
  // it down-weights would dominate chi2, so the scatter is measured robustly (1.4826 MAD).
  double scatter2 = out.reduced_chi2;
  if (o.loss != Loss::kNone) {
    std::vector<double> a;
    for (double r : out.residuals) a.push_back(std::abs(r));
    std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
    scatter2 = std::pow(1.4826 * a[a.size() / 2], 2);
  }
  const double inflate = o.inflate_by_reduced_chi2 ? std::max(1.0, scatter2) : 1.0;
  const double var_lw = cov_ok ? c(0, 0) * inflate : 0, var_lk = cov_ok ? c(1, 1) * inflate : 0;
  cov_ok = cov_ok && var_lw > 0 && var_lk > 0;
  if (cov_ok) {
    out.width.sigma = out.width.value * std::sqrt(var_lw);
    out.scale.sigma = out.scale.value * std::sqrt(var_lk);
    if (o.fit_eta) {
      const double var = c(2, 2) * inflate;
      const double u = (out.eta.value - kEtaMin) / kEtaSpan;
      out.eta.sigma = kEtaSpan * u * (1 - u) * std::sqrt(std::max(var, 0.0));
    }
    if (p.fit_floor) {
      const int i = o.fit_eta ? 3 : 2;
      out.floor.sigma = p.floor_unit * std::sqrt(std::max(c(i, i) * inflate, 0.0));
    }
    out.geometry.sample_stage.clear();
    for (int g = 0; g < p.Groups(); ++g) {
      StageOffset so = p.stage->groups[g];
      so.offset_deg = winner.delta[g];
      so.sigma_deg = std::sqrt(std::max(c(first_delta + g, first_delta + g) * inflate, 0.0));
      out.geometry.sample_stage.push_back(so);
    }
    // The statistical part: the sandwich C J^T D J C, with D_i = (sigma_stat_i / sigma_i)^2 the
    // share of each sample's variance that is statistical (LocalFit::row_sample: a row's sample;
    // a stage offset's prior is none of it, a dark set's all of it: the dark frames' noise).
    bool have_stat = j.num_rows == static_cast<int>(winner.row_sample.size());
    for (const Sample& s : p.samples) have_stat = have_stat && s.sigma_stat > 0;
    if (have_stat) {
      const int n = j.num_cols;
      Eigen::MatrixXd m = Eigen::MatrixXd::Zero(n, n);
      for (int r = 0; r < j.num_rows; ++r) {
        const int i = winner.row_sample[r];
        if (i == -1) continue;
        const double d =
            i < 0 ? 1.0 : std::pow(std::min(1.0, p.samples[i].sigma_stat / p.samples[i].sigma), 2);
        for (int a = j.rows[r]; a < j.rows[r + 1]; ++a)
          for (int b = j.rows[r]; b < j.rows[r + 1]; ++b)
            m(j.cols[a], j.cols[b]) += d * j.values[a] * j.values[b];
      }
      const Eigen::MatrixXd cs = c * m * c;
      out.width.sigma_stat = out.width.value * std::sqrt(std::max(cs(0, 0), 0.0));
      out.scale.sigma_stat = out.scale.value * std::sqrt(std::max(cs(1, 1), 0.0));
      if (p.fit_floor) {
        const int i = o.fit_eta ? 3 : 2;
        out.floor.sigma_stat = p.floor_unit * std::sqrt(std::max(cs(i, i), 0.0));
      }
    }
  }
  return cov_ok;
}

void JudgeFit(bool cov_ok, FitSummary& out) {
  const std::string constraint = ConstraintProblem(cov_ok, out);
  out.message = constraint;
  out.status = constraint.empty() ? FitStatus::kConverged : FitStatus::kUnconstrained;
  const double dof = out.n_points - out.n_params - out.n_nuisance;
  const double p_value = boost::math::gamma_q(0.5 * dof, 0.5 * out.chi2);
  if (p_value < 1e-6) {
    std::ostringstream poor;
    poor << std::setprecision(3) << "the model does not describe the data (chi2/dof "
         << out.reduced_chi2 << " over " << dof << " degrees of freedom, p = " << p_value
         << "): the width is not a measurement of the surface";
    out.message = poor.str();
    out.status = FitStatus::kPoorFit;
  }
}

bool WidthConstrained(const FitSummary& f) {
  return f.status != FitStatus::kFailed && ConstraintProblem(f.width.sigma > 0, f).empty();
}

}  // namespace gonio::fitting::internal
