#include "sim/truth/btdf_table.h"

#include <algorithm>

namespace gonio::sim {

BtdfAccumulator::BtdfAccumulator(const BtdfTable& shape, int batches)
    : shape_(shape),
      batches_(batches),
      bins_(batches, std::vector<double>(shape.n_theta * shape.n_phi, 0.0)),
      reflected_(batches, 0.0),
      transmitted_(batches, 0.0) {}

void BtdfAccumulator::Transmit(int batch, const optics::Vec3<double>& v, double w) {
  transmitted_[batch] += w;
  const int k = shape_.BinOf(v);
  if (k >= 0) bins_[batch][k] += w;
}

void BtdfAccumulator::Merge(const BtdfAccumulator& o) {
  for (int b = 0; b < batches_; ++b) {
    for (std::size_t k = 0; k < bins_[b].size(); ++k) bins_[b][k] += o.bins_[b][k];
    reflected_[b] += o.reflected_[b];
    transmitted_[b] += o.transmitted_[b];
  }
}

namespace {
// Mean and standard error of the mean of per-batch values.
void MeanSe(const std::vector<double>& x, double* mean, double* se) {
  const double n = static_cast<double>(x.size());
  double m = 0;
  for (double v : x) m += v / n;
  double var = 0;
  for (double v : x) var += (v - m) * (v - m) / std::max(1.0, n - 1);
  *mean = m;
  *se = std::sqrt(var / n);
}
}  // namespace

BtdfTable BtdfAccumulator::Finish(std::int64_t rays_per_batch) const {
  BtdfTable t = shape_;
  const int n_bins = t.n_theta * t.n_phi;
  t.f.assign(n_bins, 0);
  t.f_se.assign(n_bins, 0);
  t.rays = rays_per_batch * batches_;
  const double n = static_cast<double>(rays_per_batch);
  std::vector<double> per(batches_);
  for (int k = 0; k < n_bins; ++k) {
    const double norm = 1 / (n * t.CosSolidAngle(k / t.n_phi));
    for (int b = 0; b < batches_; ++b) per[b] = bins_[b][k] * norm;
    MeanSe(per, &t.f[k], &t.f_se[k]);
  }
  for (int b = 0; b < batches_; ++b) per[b] = transmitted_[b] / n;
  MeanSe(per, &t.transmitted, &t.transmitted_se);
  for (int b = 0; b < batches_; ++b) per[b] = reflected_[b] / n;
  MeanSe(per, &t.reflected, &t.reflected_se);
  return t;
}

}  // namespace gonio::sim
