// Runs Monte Carlo batches on worker threads, each batch into its own accumulator slot.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <thread>
#include <vector>

#include "sim/truth/btdf_table.h"
#include "sim/truth/monte_carlo.h"

namespace gonio::sim {

// The empty table a Monte Carlo run fills: its geometry and bins.
inline BtdfTable TableShape(double n_above, double n_below, double theta_i_deg,
                            const MonteCarloOptions& o) {
  BtdfTable shape;
  shape.theta_i_deg = theta_i_deg;
  shape.n_above = n_above;
  shape.n_below = n_below;
  shape.n_theta = o.n_theta;
  shape.n_phi = o.n_phi;
  return shape;
}

// body(batch, accumulator) traces one batch; batches are independent (own RNG stream), so the
// result does not depend on the number of threads.
template <typename Body>
BtdfTable RunBatches(const BtdfTable& shape, const MonteCarloOptions& o, const Body& body) {
  const int threads = std::max(
      1, o.threads > 0 ? o.threads : static_cast<int>(std::thread::hardware_concurrency()));
  std::vector<BtdfAccumulator> acc(threads, BtdfAccumulator(shape, o.batches));
  std::atomic<int> next{0};
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t)
    pool.emplace_back([&, t] {
      for (int b; (b = next.fetch_add(1)) < o.batches;) body(b, &acc[t]);
    });
  for (auto& th : pool) th.join();
  for (int t = 1; t < threads; ++t) acc[0].Merge(acc[t]);
  return acc[0].Finish(o.rays / o.batches);
}

}  // namespace gonio::sim
