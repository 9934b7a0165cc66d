// A fit's summary as JSON: what gonio-fit writes to fit_summary.json and what goniod stores in
// the fit_results table. Header-only.
#pragma once

#include <nlohmann/json.hpp>

#include "fitting/fitter.h"

namespace gonio::fitting {

inline nlohmann::json ToJson(const FitSummary& f) {
  auto param = [](const Parameter& p) {
    return nlohmann::json{{"value", p.value},
                          {"sigma", p.sigma},
                          {"sigma_stat", p.sigma_stat},
                          {"sigma_geometry", p.sigma_geometry},
                          {"sigma_floor", p.sigma_floor}};
  };
  // A geometry nuisance parameter: the offset from the stated value the data found (fitted) or
  // the prior (not), and what it moved the width by.
  auto nuisance = [](const NuisanceUse& n) {
    return nlohmann::json{{"fitted", n.fitted},
                          {"offset", n.offset},
                          {"offset_sigma", n.offset_sigma},
                          {"width_shift", n.width_shift},
                          {"width_sigma", n.width_sigma}};
  };
  nlohmann::json stage = nlohmann::json::array();
  for (const StageOffset& g : f.geometry.sample_stage)
    stage.push_back({{"sample_deg", g.sample_deg},
                     {"points", g.points},
                     {"offset_deg", g.offset_deg},
                     {"sigma_deg", g.sigma_deg}});
  return {{"model", Describe(f.model)},
          {"family", Name(f.model.family)},
          {"status", ToString(f.status)},
          {"message", f.message},
          {"width_name", WidthName(f.model.family)},
          {"width", param(f.width)},
          {"scale", param(f.scale)},
          {"eta", param(f.eta)},
          {"alpha_equivalent", f.alpha_equivalent},
          {"n_points", f.n_points},
          {"n_params", f.n_params},
          {"n_nuisance", f.n_nuisance},
          {"chi2", f.chi2},
          {"reduced_chi2", f.reduced_chi2},
          {"aic", f.aic},
          {"bic", f.bic},
          {"iterations", f.iterations},
          {"local_fits", f.local_fits},
          {"points_in_lobe", f.points_in_lobe},
          {"floor", param(f.floor)},
          {"floor_fitted", f.floor_fitted},
          {"floor_choice", f.floor_choice},
          {"floor_width_shift", f.floor_width_shift},
          {"response",
           {{"samples_with_response", f.response.samples_with_response},
            {"rectangle", f.response.rectangle},
            {"apertures", f.response.apertures},
            {"rays", f.response.rays},
            {"rounds", f.response.rounds},
            {"capped", f.response.capped},
            {"capped_largest", f.response.capped_largest},
            {"traced", f.response.traced},
            {"capped_untraced_largest", f.response.capped_untraced_largest}}},
          {"dark",
           {{"sets", f.dark.sets}, {"samples", f.dark.samples}, {"largest_z", f.dark.largest_z}}},
          {"geometry",
           {{"stated", f.geometry.stated},
            {"angle_max_fraction", f.geometry.angle_max_fraction},
            {"angle_in_fit", f.geometry.angle_in_fit},
            {"left_out", f.geometry.left_out},
            {"width_thickness", f.geometry.width_thickness},
            {"width_rectangle", f.geometry.width_rectangle},
            {"thickness_mm", nuisance(f.geometry.thickness)},
            {"rectangle_x_px", nuisance(f.geometry.rectangle_x)},
            {"rectangle_y_px", nuisance(f.geometry.rectangle_y)},
            {"sample_stage", stage},
            {"note", f.geometry.note}}},
          {"seconds", f.seconds}};
}

}  // namespace gonio::fitting
