// Comparing a Monte Carlo table with an analytic BTDF on the same bins.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "sim/truth/btdf_table.h"

namespace gonio::sim {

// f_t(l, v): light l above, view v below (optics conventions).
using BtdfFunction =
    std::function<double(const optics::Vec3<double>& l, const optics::Vec3<double>& v)>;

// The analytic model averaged over each bin the way the table is (|cos theta_o|-weighted),
// by 4 x 4 Gauss-Legendre points per bin.
std::vector<double> TabulateModel(const BtdfTable& shape, const BtdfFunction& f_t);

struct TableDifference {
  // sum |f_mc - f_model| cos dOmega / sum f_mc cos dOmega: 0 identical, 2 disjoint lobes.
  double l1_relative = 0;
  // The same sum for pure Monte Carlo noise (sqrt(2/pi) * se per bin): what l1_relative would be
  // if the model were exact.
  double l1_noise = 0;
  double transmitted_mc = 0, transmitted_model = 0;
};
TableDifference Compare(const BtdfTable& mc, const std::vector<double>& model_bins);
// Two Monte Carlo tables of the same shape: l1_noise combines both tables' errors.
TableDifference CompareTables(const BtdfTable& a, const BtdfTable& b);
// The part of a difference not explained by Monte Carlo noise: max(0, l1 - noise).
inline double ExcessL1(const TableDifference& d) {
  return d.l1_relative > d.l1_noise ? d.l1_relative - d.l1_noise : 0.0;
}

// The single-scattering models of the project, for the table's geometry: Walter 2007 eq. 21
// (Beckmann, alpha = 2/s, separable Smith G) and Sun 2008 eq. 25.
BtdfFunction WalterBeckmannModel(double s, double n_above, double n_below);
BtdfFunction Sun2008Model(double s, double n_above, double n_below);

}  // namespace gonio::sim
