// gonio-fit: fits microfacet models to a CSV of BTDF*cos samples (BRDF*cos where the side column
// says reflection) and prints a table like Figure 12 of Walter 2007. With several incidences and a
// normal-incidence sweep among them it follows the paper's protocol: fit at normal incidence,
// predict the other incidences, and fit all jointly.
//
//   gonio-fit samples.csv --model beckmann,ggx --out fit/
//
// Exit status: 0 when at least one model was fitted, 1 when every fit failed, 2 for bad input.
#include <unistd.h>
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
#include <optional>
#include <sstream>

#include "common/progress_line.h"
#include "common/wrap.h"
#include "fitting/empirical_d.h"
#include "fitting/fit_protocol.h"
#include "fitting/fitter.h"
#include "fitting/samples_csv.h"
#include "fitting/summary_json.h"
#include "fitting/tools/fit_report.h"

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

// --out: the curves of the fits that describe the lobe, the empirical and fitted D, and the JSON
// summary of every fit and the model choice.
Status WriteOutputs(const std::string& out_dir, const std::string& csv_path,
                    std::span<const Sample> samples, const FitProtocolResult& result) {
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

// The command line, parsed and checked: what a fit is asked to do.
struct Command {
  std::string csv_path, out_dir;
  std::vector<ModelSpec> models;
  FitOptions base;
  double systematic = 0;
  bool quiet = false, verbose = false, explain = false;
};

// Fills `c` from the command line; nullopt to go on, else the exit code (help printed, or a bad
// option named on standard error).
std::optional<int> ParseCommand(int argc, char** argv, Command& c) {
  CLI::App app{"Fit microfacet models (Walter 2007, Sun 2008) to BTDF*cos or BRDF*cos samples"};
  std::string models_arg = "beckmann,ggx", loss_arg = "none", floor_arg = "auto";
  std::string held_arg = "traced";
  bool point_model = false, rational = false;
  double start = 0;
  app.add_option("samples", c.csv_path,
                 "CSV with columns theta_l_deg, theta_v_deg, value, sigma [, phi_l_deg, phi_v_deg]")
      ->required();
  app.add_option("--model", models_arg, "comma-separated: beckmann, ggx, phong, sun2008")
      ->capture_default_str();
  app.add_option("--eta", c.base.eta, "refractive index of the sample (fixed, or start)")
      ->capture_default_str();
  app.add_flag("--fit-eta", c.base.fit_eta, "fit eta as a third parameter");
  app.add_option("--loss", loss_arg, "none, huber or cauchy (robust against stray light)")
      ->check(CLI::IsMember({"none", "huber", "cauchy"}))
      ->capture_default_str();
  app.add_option("--loss-scale", c.base.loss_scale, "robust loss scale in sigmas")
      ->capture_default_str();
  app.add_option("--systematic", c.systematic,
                 "relative systematic uncertainty added in quadrature to every sigma (e.g. 0.01 "
                 "for a bench whose stored sigma is statistical only)")
      ->capture_default_str();
  app.add_option("--start", start,
                 "starting width (alpha, exponent or s) in addition to the automatic starts");
  app.add_flag("--rational-g1", rational, "Beckmann with Walter's rational G1 (eq. 27)");
  app.add_option("--floor", floor_arg,
                 "a constant floor (stray light): auto (kept when BIC prefers it or when leaving "
                 "it out moves the width by more than half its sigma; where BIC does not, that "
                 "move is in sigma either way), on or off")
      ->check(CLI::IsMember({"auto", "on", "off"}))
      ->capture_default_str();
  app.add_flag("--point-model", point_model,
               "ignore the samples' instrument response (an export's '# response:' line)");
  app.add_option("--response-tolerance", c.base.response_tolerance,
                 "use a sample's response where it changes the prediction by more than this "
                 "fraction of its sigma")
      ->capture_default_str();
  app.add_option("--max-response-rays", c.base.max_response_rays,
                 "the most rays one sample's model may hold; past it the model is corrected to "
                 "the next level, whose error joins the sample's sigma (--held-error)")
      ->capture_default_str();
  app.add_option("--held-error", held_arg,
                 "a held sample's error: traced (one level finer, once at the solution) or next "
                 "(the whole change to the next level: no more rays, conservative)")
      ->check(CLI::IsMember({"traced", "next"}))
      ->capture_default_str();
  app.add_flag("--explain", c.explain,
               "after each fit, how the geometry, the instrument response, the ray budget, the "
               "dark sets and the floor's choice entered it");
  app.add_flag("-v,--verbose", c.verbose,
               "every step of every solve on standard error, and --explain");
  app.add_flag("-q,--quiet", c.quiet, "no progress on standard error, however long the fit");
  app.add_option("--out", c.out_dir,
                 "directory for fit_curves.csv, empirical_d.csv, fitted_d.csv, fit_summary.json");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  auto fail = [](const std::string& msg) {
    std::cerr << "gonio-fit: error: " << msg << "\n";
    return 2;
  };
  auto models = ParseModels(Split(models_arg), rational ? gonio::optics::SmithG1::kRational
                                                        : gonio::optics::SmithG1::kExact);
  if (!models) return fail("--model: " + models.error().message);
  c.models = *models;
  c.base.loss = loss_arg == "huber"    ? Loss::kHuber
                : loss_arg == "cauchy" ? Loss::kCauchy
                                       : Loss::kNone;
  c.base.floor = floor_arg == "on" ? Floor::kFit : floor_arg == "off" ? Floor::kOff : Floor::kAuto;
  c.base.held_error = held_arg == "next" ? HeldError::kNextChange : HeldError::kTraced;
  if (start != 0) c.base.initial_width = start;
  c.base.use_response = !point_model;
  if (auto s = c.base.Validate(); !s) return fail(s.error().message);
  if (!std::isfinite(c.systematic) || c.systematic < 0 || c.systematic >= 1)
    return fail("--systematic: " + std::to_string(c.systematic) + " is not a fraction in [0, 1)");
  c.explain = c.explain || c.verbose;
  return std::nullopt;
}

}  // namespace

int main(int argc, char** argv) {
  Command c;
  if (auto rc = ParseCommand(argc, argv, c)) return *rc;
  auto samples = ReadSamplesCsv(c.csv_path);
  if (!samples) {
    std::cerr << "gonio-fit: error: " << samples.error().message << "\n";
    return 2;
  }
  if (auto s = ValidateSamples(*samples, c.base.NumParams(), c.csv_path); !s) {
    std::cerr << "gonio-fit: error: " << s.error().message << "\n";
    return 2;
  }
  if (c.systematic > 0) *samples = WithSystematic(*samples, c.systematic);

  // Progress on standard error: on a terminal one line redrawn (each stage, each solve's step);
  // in a log a line per model and part; with -v every step with its time.
  ProgressLine progress(std::cerr, !c.quiet && !c.verbose && ::isatty(2) != 0);
  const auto t0 = std::chrono::steady_clock::now();
  auto elapsed = [t0] {
    return std::lround(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  };
  FitProtocolOptions protocol;
  protocol.models = c.models;
  protocol.base = c.base;
  if (c.verbose) {
    protocol.base.progress = [&elapsed](const std::string& what) {
      std::cerr << "gonio-fit: [" << elapsed() << " s] " << what << std::endl;
    };
  } else if (!c.quiet) {
    protocol.stage = [&](const std::string& what) {
      progress.Stage("gonio-fit: [" + std::to_string(elapsed()) + " s] fitting " + what);
    };
    if (progress.terminal())
      protocol.base.progress = [&](const std::string& s) { progress.Step(s); };
  }
  auto run = RunFitProtocol(*samples, protocol);
  progress.Done();
  if (!run) {
    std::cerr << "gonio-fit: error: " << run.error().message << "\n";
    return 1;
  }
  PrintSamplesLine(std::cout, samples->size(), *run, c.base.eta, c.base.fit_eta);
  PrintProtocolResult(std::cout, *run, ReportOptions{.explain = c.explain});
  if (!c.out_dir.empty()) {
    if (Status w = WriteOutputs(c.out_dir, c.csv_path, *samples, *run); !w.ok()) {
      std::cerr << "gonio-fit: error: " << w.error().message << "\n";
      return 2;
    }
    std::cout << "\n"
              << Wrap("wrote the curves, the empirical D and fit_summary.json to " + c.out_dir +
                          " (docs/fitting.md)",
                      kReportColumns, "", "  ");
  }
  return run->AnyFitted() ? 0 : 1;
}
