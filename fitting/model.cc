#include "fitting/model.h"

#include <cmath>

namespace gonio::fitting {

const char* Name(Family f) {
  switch (f) {
    case Family::kBeckmann:
      return "beckmann";
    case Family::kGgx:
      return "ggx";
    case Family::kPhong:
      return "phong";
    case Family::kSun2008:
      return "sun2008";
  }
  return "?";
}

std::optional<Family> ParseFamily(std::string_view name) {
  for (Family f : kAllFamilies)
    if (name == Name(f)) return f;
  return std::nullopt;
}

const char* WidthName(Family f) {
  switch (f) {
    case Family::kPhong:
      return "exponent";
    case Family::kSun2008:
      return "s";
    default:
      return "alpha";
  }
}

double AlphaEquivalent(Family f, double width) {
  switch (f) {
    case Family::kPhong:
      return std::sqrt(2.0 / (width + 2.0));
    case Family::kSun2008:
      return optics::Sun2008EquivalentAlpha(width);
    default:
      return width;
  }
}

std::optional<double> WidthFromAlphaEquivalent(Family f, double alpha) {
  if (!(alpha > 0)) return std::nullopt;
  switch (f) {
    case Family::kPhong: {
      const double e = optics::BeckmannToPhongExponent(alpha);
      if (!(e > 0)) return std::nullopt;
      return e;
    }
    case Family::kSun2008:
      return 2.0 / alpha;
    default:
      return alpha;
  }
}

std::string Describe(const ModelSpec& m) {
  std::string s = Name(m.family);
  if (m.family == Family::kBeckmann && m.g1 == optics::SmithG1::kRational) s += " (rational G1)";
  return s;
}

}  // namespace gonio::fitting
