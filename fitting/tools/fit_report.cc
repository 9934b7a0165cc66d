#include "fitting/tools/fit_report.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "common/wrap.h"

namespace gonio::fitting {

namespace {

// The value and its sigma, with at least two significant digits of the sigma.
std::string PlusMinus(const Parameter& p, int precision) {
  if (p.sigma > 0 && std::isfinite(p.sigma))
    precision = std::clamp(1 - static_cast<int>(std::floor(std::log10(p.sigma))), precision, 12);
  std::ostringstream os;
  os << std::fixed << std::setprecision(precision) << p.value;
  if (p.sigma > 0) os << " +- " << p.sigma;
  return os.str();
}

std::string Number(double v, int precision) {
  std::ostringstream os;
  os << std::setprecision(precision) << v;
  return os.str();
}

// A cell padded to its column, or followed by one space where it is wider.
std::string Cell(const std::string& text, std::size_t w) {
  return text.size() < w ? text + std::string(w - text.size(), ' ') : text + " ";
}

std::string Trimmed(std::string s) {
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

// The model's name in the table's first column (10 characters at most).
std::string TableName(const ModelSpec& m) {
  std::string s = Name(m.family);
  if (m.family == Family::kBeckmann && m.g1 == optics::SmithG1::kRational) s += "-r";
  return s;
}

// Text wrapped under a fit's row.
void Detail(std::ostream& out, const std::string& text) {
  out << Wrap(text, kReportColumns, "    ", "      ");
}

// The width's sigma and its parts, each in quadrature (Parameter).
std::string SigmaSplit(const FitSummary& f) {
  const Parameter& w = f.width;
  const double instrument = std::sqrt(
      std::max(0.0, w.sigma * w.sigma - w.sigma_stat * w.sigma_stat -
                        w.sigma_geometry * w.sigma_geometry - w.sigma_floor * w.sigma_floor));
  std::ostringstream s;
  s << std::setprecision(3) << WidthName(f.model.family) << "'s sigma " << w.sigma
    << ": statistical " << w.sigma_stat << ", instrument " << instrument << ", geometry "
    << w.sigma_geometry;
  if (w.sigma_floor > 0) s << ", floor " << w.sigma_floor;
  return s.str();
}

// The long account of one fit: what each part of the instrument model did in it.
void PrintExplanation(std::ostream& out, const FitSummary& f) {
  std::ostringstream s;
  if (f.width.sigma_stat > 0 || f.width.sigma_geometry > 0)
    Detail(out,
           "sigma's parts: statistical (shot, read, dark), instrument (lamp, monitor" +
               std::string(f.reduced_chi2 > 1 ? ", chi2 inflation" : "") +
               "), geometry (angles, thickness, rectangle)" +
               (f.width.sigma_floor > 0 ? ", floor (the floor's choice, where BIC cannot show it)"
                                        : ""));
  if (f.model.family != Family::kBeckmann && f.model.family != Family::kGgx)
    Detail(out, "Beckmann-equivalent alpha " + Number(f.alpha_equivalent, 4));
  if (!f.geometry.note.empty()) Detail(out, "geometry: " + f.geometry.note);
  if (f.response.samples_with_response > 0) {
    s << "instrument response: " << f.response.rectangle << " of " << f.n_points
      << " samples through the rectangle's rays (" << f.response.apertures
      << " with the apertures too), " << f.response.rays << " model evaluations per pass, "
      << f.response.rounds << " solve(s); " << std::setprecision(3) << f.seconds << " s";
    Detail(out, s.str());
    s.str("");
  }
  if (f.response.capped > 0) {
    s << "ray budget: " << f.response.capped
      << " sample(s) modelled below the level the tolerance asked for (more than "
         "--max-response-rays), corrected to the next level; ";
    if (f.response.traced > 0)
      s << "its error, traced one level finer for " << f.response.traced
        << " of them, is in their sigma, at most " << std::setprecision(3)
        << f.response.capped_largest << " of the sample's own (the change to the next level was "
        << f.response.capped_untraced_largest << ")";
    else
      s << "the difference is in their sigma, at most " << std::setprecision(3)
        << f.response.capped_largest << " of the sample's own";
    Detail(out, s.str());
    s.str("");
  }
  if (f.dark.sets > 0) {
    s << "dark sets: " << f.dark.sets << " shared error(s) in the fit, over " << f.dark.samples
      << " samples (the largest found: " << std::setprecision(2) << f.dark.largest_z
      << " of its sigma)";
    Detail(out, s.str());
  }
  if (!f.floor_choice.empty()) Detail(out, f.floor_choice);
}

void PrintFits(std::ostream& out, const std::string& title, const std::vector<FitSummary>& fits,
               const ModelChoice& choice, const ReportOptions& options) {
  out << "\n" << title << "\n";
  out << Cell("model", 11) << Cell("scale k", 21) << Cell("width", 29) << Cell("chi2/dof", 10)
      << Cell("dBIC", 10) << "status\n";
  for (std::size_t k = 0; k < fits.size(); ++k) {
    const FitSummary& f = fits[k];
    out << Cell(TableName(f.model), 11) << Cell(PlusMinus(f.scale, 4), 21)
        << Cell(std::string(WidthName(f.model.family)) + " " + PlusMinus(f.width, 4), 29)
        << Cell(Number(f.reduced_chi2, 4), 10) << Cell(Number(choice.delta_bic[k], 3), 10)
        << ToString(f.status) << "\n";
    // A warning (why the fit is not a measurement) is shown whatever the options.
    if (!f.message.empty()) Detail(out, f.message);
    // A width's parts and the floor where the width is a measurement (the rest under --explain).
    const bool measured = f.status == FitStatus::kConverged;
    if (measured && (f.width.sigma_stat > 0 || f.width.sigma_geometry > 0))
      Detail(out, SigmaSplit(f));
    if (f.floor_fitted && (measured || options.explain))
      Detail(out, "floor " + PlusMinus(f.floor, 4) + " (value units)");
    if (options.explain) PrintExplanation(out, f);
  }
  out << Wrap("model choice: " + choice.reason, kReportColumns, "", "  ");
}

// Walter's Figures 10-11: how well each normal-incidence fit predicts the other incidences.
void PrintPredictions(std::ostream& out, const FitProtocolResult& r) {
  out << "\nPrediction of the other incidences from the normal-incidence fit\n"
         "(rms relative error over samples above 1 % of the peak, chi2/n in brackets):\n";
  std::string line = Cell("theta_l", 10);
  for (const auto& f : r.normal_fits) line += Cell(TableName(f.model), 22);
  out << Trimmed(line) << "\n";
  for (std::size_t g = 0; g < r.groups.size(); ++g) {
    line = Cell(Number(r.groups[g].theta_l_deg, 4), 10);
    for (const auto& p : r.predictions)
      line += Cell(
          Number(100 * p[g].rms_relative, 3) + " %  (" + Number(p[g].reduced_chi2, 3) + ")", 22);
    out << Trimmed(line) << "\n";
  }
}

}  // namespace

void PrintSamplesLine(std::ostream& out, std::size_t samples, const FitProtocolResult& result,
                      double eta, bool eta_fitted) {
  std::ostringstream s;
  s << "gonio-fit: " << samples << " samples, " << result.groups.size()
    << (result.groups.size() == 1 ? " incidence:" : " incidences:");
  for (const auto& g : result.groups) s << " " << g.theta_l_deg << " (" << g.samples.size() << ")";
  s << "; eta " << (eta_fitted ? "fitted from " : "") << eta << (eta_fitted ? "" : " (fixed)");
  for (const auto& f : result.joint_fits)
    if (f.model.family == Family::kBeckmann && f.model.g1 == optics::SmithG1::kRational) {
      s << "; beckmann-r: Beckmann with Walter's rational G1 (eq. 27)";
      break;
    }
  out << Wrap(s.str(), kReportColumns, "", "  ");
  if (eta_fitted)
    for (const auto& f : result.joint_fits)
      out << "  " << TableName(f.model) << ": eta " << PlusMinus(f.eta, 3) << "\n";
}

void PrintProtocolResult(std::ostream& out, const FitProtocolResult& result,
                         const ReportOptions& options) {
  if (result.protocol) {
    PrintFits(out,
              "Fit at normal incidence (Walter 2007 section 6, Figure 12):", result.normal_fits,
              SelectModel(result.normal_fits), options);
    PrintPredictions(out, result);
  }
  PrintFits(out, result.protocol ? "Joint fit of all incidences:" : "Fit:", result.joint_fits,
            result.choice, options);
}

}  // namespace gonio::fitting
