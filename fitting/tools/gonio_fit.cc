// gonio-fit: fits microfacet models to a CSV of BTDF*cos samples (BRDF*cos where the side column
// says reflection) and prints a table like Figure 12 of Walter 2007. With several incidences and a
// normal-incidence sweep among them it follows the paper's protocol: fit at normal incidence,
// predict the other incidences, and fit all jointly.
//
//   gonio-fit samples.csv --model beckmann,ggx --out fit/
//
// Exit status: 0 when at least one model was fitted, 1 when every fit failed, 2 for bad input.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "fitting/fitter.h"
#include "fitting/protocol.h"
#include "fitting/samples_csv.h"
#include "fitting/summary_json.h"

namespace {

using namespace gonio;
using namespace gonio::fitting;

std::vector<std::string> Split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

// The value and its sigma, with at least two significant digits of the sigma.
std::string PlusMinus(const Parameter& p, int precision) {
  if (p.sigma > 0 && std::isfinite(p.sigma))
    precision = std::clamp(1 - static_cast<int>(std::floor(std::log10(p.sigma))), precision, 12);
  std::ostringstream os;
  os << std::fixed << std::setprecision(precision) << p.value;
  if (p.sigma > 0) os << " +- " << p.sigma;
  return os.str();
}

void PrintFits(const std::string& title, const std::vector<FitSummary>& fits,
               const ModelChoice& choice) {
  std::cout << "\n" << title << "\n";
  std::cout << std::left << std::setw(24) << "model" << std::setw(22) << "scale k" << std::setw(30)
            << "width" << std::setw(10) << "alpha_eq" << std::setw(18) << "eta" << std::setw(10)
            << "chi2/dof" << std::setw(10) << "dBIC"
            << "status\n";
  // A cell padded to its column, or followed by one space where it is wider (a width with many
  // digits ran into alpha_eq: "0.000000950.023").
  auto cell = [](const std::string& text, std::size_t w) {
    return text.size() < w ? text + std::string(w - text.size(), ' ') : text + " ";
  };
  auto number = [](double v, int precision) {
    std::ostringstream os;
    os << std::setprecision(precision) << v;
    return os.str();
  };
  for (std::size_t k = 0; k < fits.size(); ++k) {
    const FitSummary& f = fits[k];
    std::ostringstream width;
    width << WidthName(f.model.family) << " " << PlusMinus(f.width, 4);
    std::cout << cell(Describe(f.model), 24) << cell(PlusMinus(f.scale, 4), 22)
              << cell(width.str(), 30) << cell(number(f.alpha_equivalent, 4), 10)
              << cell(PlusMinus(f.eta, 3), 18) << cell(number(f.reduced_chi2, 4), 10)
              << cell(number(choice.delta_bic[k], 3), 10) << ToString(f.status) << "\n";
    if (!f.message.empty()) std::cout << "    " << Describe(f.model) << ": " << f.message << "\n";
    if (f.width.sigma_stat > 0 || f.width.sigma_geometry > 0) {
      const Parameter& w = f.width;
      std::cout << "    " << WidthName(f.model.family) << "'s sigma " << std::setprecision(3)
                << w.sigma << ": statistical (shot, read, dark) " << w.sigma_stat
                << ", instrument (lamp, monitor" << (f.reduced_chi2 > 1 ? ", chi2 inflation" : "")
                << ") "
                << std::sqrt(std::max(0.0, w.sigma * w.sigma - w.sigma_stat * w.sigma_stat -
                                               w.sigma_geometry * w.sigma_geometry -
                                               w.sigma_floor * w.sigma_floor))
                << ", geometry " << w.sigma_geometry;
      if (w.sigma_floor > 0) std::cout << ", the floor's choice " << w.sigma_floor;
      std::cout << "\n";
    }
    if (!f.geometry.note.empty()) std::cout << "    geometry: " << f.geometry.note << "\n";
    if (f.response.samples_with_response > 0)
      std::cout << "    instrument response: " << f.response.rectangle << " of " << f.n_points
                << " samples through the rectangle's rays (" << f.response.apertures
                << " with the apertures too), " << f.response.rays
                << " model evaluations per pass, " << f.response.rounds << " solve(s); "
                << std::setprecision(3) << f.seconds << " s\n";
    if (f.response.capped > 0 && f.response.traced > 0)
      std::cout << "    ray budget: " << f.response.capped
                << " sample(s) modelled below the level the tolerance asked for (more than "
                   "--max-response-rays), corrected to the next level; its error, traced one "
                   "level finer for "
                << f.response.traced << " of them, is in their sigma, at most "
                << std::setprecision(3) << f.response.capped_largest
                << " of the sample's own (the change to the next level was "
                << f.response.capped_untraced_largest << ")\n";
    else if (f.response.capped > 0)
      std::cout << "    ray budget: " << f.response.capped
                << " sample(s) modelled below the level the tolerance asked for (more than "
                   "--max-response-rays), corrected to the next level; the difference is in "
                   "their sigma, at most "
                << std::setprecision(3) << f.response.capped_largest << " of the sample's own\n";
    if (f.dark.sets > 0)
      std::cout << "    dark sets: " << f.dark.sets << " shared error(s) in the fit, over "
                << f.dark.samples << " samples (the largest found: " << std::setprecision(2)
                << f.dark.largest_z << " of its sigma)\n";
    if (f.floor_fitted)
      std::cout << "    floor: " << PlusMinus(f.floor, 6) << " (" << f.floor_choice << ")\n";
    else if (!f.floor_choice.empty())
      std::cout << "    " << f.floor_choice << "\n";
  }
  std::cout << "model choice: " << choice.reason << "\n";
}

// The paper's protocol: the normal-incidence fits and their predictions of the other incidences.
void PrintProtocol(const ProtocolResult& r) {
  PrintFits("Fit at normal incidence (Walter 2007 section 6, Figure 12):", r.normal_fits,
            SelectModel(r.normal_fits));
  std::cout << "\nPrediction of the other incidences from the normal-incidence fit "
               "(rms relative error over samples above 1 % of peak; chi2/n):\n";
  std::cout << std::left << std::setw(12) << "theta_l";
  for (const auto& f : r.normal_fits) std::cout << std::setw(28) << Describe(f.model);
  std::cout << "\n";
  for (std::size_t g = 0; g < r.groups.size(); ++g) {
    std::cout << std::setw(12) << r.groups[g].theta_l_deg;
    for (const auto& p : r.predictions) {
      std::ostringstream cell;
      cell << std::setprecision(3) << 100 * p[g].rms_relative << " %  (" << p[g].reduced_chi2
           << ")";
      std::cout << std::setw(28) << cell.str();
    }
    std::cout << "\n";
  }
}

// --out: the curves of the fits that describe the lobe, the empirical and fitted D, and the JSON
// summary of every fit and the model choice.
Status WriteOutputs(const std::string& out_dir, const std::string& csv_path,
                    std::span<const Sample> samples, const ProtocolResult& result) {
  const std::vector<FitSummary>& normal_fits = result.normal_fits;
  const std::vector<FitSummary>& joint_fits = result.joint_fits;
  const ModelChoice& choice = result.choice;
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) return InvalidArgument(out_dir + ": cannot create: " + ec.message());
  const auto& curve_fits = result.curve_fits();
  auto write_curves = [&samples](std::ofstream& curves, const std::vector<FitSummary>& fits) {
    curves << "theta_l_deg,theta_v_deg,value,sigma";
    for (const auto& f : fits) curves << ",pred_" << Name(f.model.family);
    curves << "\n" << std::setprecision(10);
    for (const Sample& s : samples) {
      curves << ThetaLightDeg(s) << ',' << ThetaViewDeg(s) << ',' << s.value << ',' << s.sigma;
      for (const auto& f : fits) curves << ',' << Predict(f, s);
      curves << "\n";
    }
  };
  std::ofstream curves(out_dir + "/fit_curves.csv");
  write_curves(curves, curve_fits);
  // With the protocol the curves above are the normal-incidence fits' (they describe the lobe);
  // the joint fits' own residuals, each incidence at its own sample-stage offset, go beside them.
  if (&curve_fits != &joint_fits) {
    std::ofstream joint(out_dir + "/fit_curves_joint.csv");
    write_curves(joint, joint_fits);
    if (!joint) return InvalidArgument(out_dir + ": writing fit_curves_joint.csv failed");
  }
  std::ofstream emp(out_dir + "/empirical_d.csv");
  emp << "model,theta_h_deg,d,d_sigma\n" << std::setprecision(10);
  for (const auto& f : curve_fits)
    for (const auto& p : EmpiricalD(samples, f.scale.value, f.eta.value))
      emp << Name(f.model.family) << ',' << p.theta_h_deg << ',' << p.d << ',' << p.d_sigma << "\n";
  std::ofstream fd(out_dir + "/fitted_d.csv");
  fd << "theta_h_deg";
  for (const auto& f : curve_fits) fd << ",d_" << Name(f.model.family);
  fd << "\n" << std::setprecision(10);
  for (double t = 0; t <= 80.0 + 1e-9; t += 0.25) {
    fd << t;
    for (const auto& f : curve_fits) fd << ',' << FittedD(f, t);
    fd << "\n";
  }
  nlohmann::json j;
  j["samples"] = csv_path;
  for (const auto& f : normal_fits) j["normal_incidence_fits"].push_back(ToJson(f));
  for (const auto& f : joint_fits) j["fits"].push_back(ToJson(f));
  j["model_choice"] = {{"chosen", choice.chosen ? Describe(joint_fits[*choice.chosen].model) : ""},
                       {"reason", choice.reason}};
  std::ofstream(out_dir + "/fit_summary.json") << j.dump(2) << "\n";
  if (!curves || !emp || !fd) return InvalidArgument(out_dir + ": writing the output files failed");
  return OkStatus();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Fit microfacet models (Walter 2007, Sun 2008) to BTDF*cos or BRDF*cos samples"};
  std::string csv_path, models_arg = "beckmann,ggx", loss_arg = "none", out_dir, floor_arg = "auto";
  bool point_model = false;
  FitOptions base;
  double start = 0, systematic = 0;
  bool rational = false;
  app.add_option("samples", csv_path,
                 "CSV with columns theta_l_deg, theta_v_deg, value, sigma [, phi_l_deg, phi_v_deg]")
      ->required();
  app.add_option("--model", models_arg, "comma-separated: beckmann, ggx, phong, sun2008")
      ->capture_default_str();
  app.add_option("--eta", base.eta, "refractive index of the sample (fixed, or start)")
      ->capture_default_str();
  app.add_flag("--fit-eta", base.fit_eta, "fit eta as a third parameter");
  app.add_option("--loss", loss_arg, "none, huber or cauchy (robust against stray light)")
      ->capture_default_str();
  app.add_option("--loss-scale", base.loss_scale, "robust loss scale in sigmas")
      ->capture_default_str();
  app.add_option("--systematic", systematic,
                 "relative systematic uncertainty added in quadrature to every sigma (e.g. 0.01 "
                 "for a bench whose stored sigma is statistical only)")
      ->capture_default_str();
  app.add_option("--start", start,
                 "starting width (alpha, exponent or s) in addition to the automatic starts");
  app.add_flag("--rational-g1", rational, "Beckmann with Walter's rational G1 (eq. 27)");
  app.add_option(
         "--floor", floor_arg,
         "a constant floor (stray light): auto (kept when BIC prefers it or when leaving it out "
         "moves the width by more than half its sigma; where BIC does not, that move is in "
         "sigma either way), on or off")
      ->capture_default_str();
  app.add_flag("--point-model", point_model,
               "ignore the samples' instrument response (an export's '# response:' line)");
  app.add_option("--response-tolerance", base.response_tolerance,
                 "use a sample's response where it changes the prediction by more than this "
                 "fraction of its sigma")
      ->capture_default_str();
  app.add_option("--max-response-rays", base.max_response_rays,
                 "the most rays one sample's model may hold; past it the model is corrected to "
                 "the next level, whose error joins the sample's sigma (--held-error)")
      ->capture_default_str();
  std::string held_arg = "traced";
  app.add_option("--held-error", held_arg,
                 "a held sample's error: traced (one level finer, once at the solution) or next "
                 "(the whole change to the next level: no more rays, conservative)")
      ->check(CLI::IsMember({"traced", "next"}))
      ->capture_default_str();
  bool quiet = false;
  app.add_flag("--quiet", quiet, "no progress on standard error, however long the fit");
  app.add_option("--out", out_dir,
                 "directory for fit_curves.csv, empirical_d.csv, fitted_d.csv, fit_summary.json");
  CLI11_PARSE(app, argc, argv);

  auto fail_input = [](const std::string& msg) {
    std::cerr << "gonio-fit: error: " << msg << "\n";
    return 2;
  };
  const auto names = Split(models_arg);
  auto models = ParseModels(
      names, rational ? gonio::optics::SmithG1::kRational : gonio::optics::SmithG1::kExact);
  if (!models) return fail_input("--model: " + models.error().message);
  if (loss_arg == "huber")
    base.loss = Loss::kHuber;
  else if (loss_arg == "cauchy")
    base.loss = Loss::kCauchy;
  else if (loss_arg != "none")
    return fail_input("--loss: '" + loss_arg + "' is not none, huber or cauchy");
  if (start != 0) base.initial_width = start;
  base.held_error = held_arg == "next" ? HeldError::kNextChange : HeldError::kTraced;
  if (floor_arg == "auto")
    base.floor = Floor::kAuto;
  else if (floor_arg == "on")
    base.floor = Floor::kFit;
  else if (floor_arg == "off")
    base.floor = Floor::kOff;
  else
    return fail_input("--floor: '" + floor_arg + "' is not auto, on or off");
  base.use_response = !point_model;
  if (auto s = base.Validate(); !s) return fail_input(s.error().message);
  if (!std::isfinite(systematic) || systematic < 0 || systematic >= 1)
    return fail_input("--systematic: " + std::to_string(systematic) +
                      " is not a fraction in [0, 1)");

  auto samples = ReadSamplesCsv(csv_path);
  if (!samples) return fail_input(samples.error().message);
  if (auto s = ValidateSamples(*samples, base.NumParams(), csv_path); !s)
    return fail_input(s.error().message);
  if (systematic > 0) *samples = WithSystematic(*samples, systematic);

  // Progress on standard error once a fit has run for a few seconds (a narrow lobe under a large
  // rectangle takes minutes); short fits stay quiet.
  const auto t0 = std::chrono::steady_clock::now();
  if (!quiet)
    base.progress = [t0](const std::string& what) {
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (s >= 5) std::cerr << "gonio-fit: [" << std::lround(s) << " s] " << what << std::endl;
    };
  auto run = RunProtocol(*samples, ProtocolOptions{.models = *models, .base = base});
  if (!run) {
    std::cerr << "gonio-fit: error: " << run.error().message << "\n";
    return 1;
  }
  const ProtocolResult& result = *run;
  std::cout << "gonio-fit: " << samples->size() << " samples from " << csv_path << ", "
            << result.groups.size() << " incidence(s):";
  for (const auto& g : result.groups)
    std::cout << " " << g.theta_l_deg << " (" << g.samples.size() << ")";
  std::cout << "\n";
  if (result.protocol) PrintProtocol(result);
  PrintFits(result.protocol ? "Joint fit of all incidences:" : "Fit:", result.joint_fits,
            result.choice);

  if (!out_dir.empty()) {
    if (Status w = WriteOutputs(out_dir, csv_path, *samples, result); !w.ok())
      return fail_input(w.error().message);
    std::cout << "\nwrote " << out_dir
              << "/{fit_curves.csv, empirical_d.csv, fitted_d.csv, fit_summary.json"
              << (result.protocol ? ", fit_curves_joint.csv" : "") << "}\n";
  }
  return result.AnyFitted() ? 0 : 1;
}
