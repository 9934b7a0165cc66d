// Small dependency-free vector math for the optics library (in the manner of pbrt-v4's util/).
//
// Everything is templated on the scalar T so that ceres::Jet flows through unchanged. Math
// functions are called unqualified after `using std::f`, so that argument-dependent lookup finds
// the Jet overloads in namespace ceres.
//
// Frame: the macrosurface normal n is +z. A direction is a unit Vec3; CosTheta(w) = w.z.
#pragma once

#include <cmath>
#include <numbers>

namespace gonio::optics {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kDeg = kPi / 180;  // radians per degree
inline constexpr double kInvPi = std::numbers::inv_pi;

template <typename T>
constexpr T Sqr(const T& x) {
  return x * x;
}

// sqrt clamped at zero: rounding may make a mathematically non-negative argument slightly < 0.
template <typename T>
T SafeSqrt(const T& x) {
  using std::sqrt;
  return x > T(0) ? sqrt(x) : T(0);
}

template <typename T>
struct Vec3 {
  T x{}, y{}, z{};

  constexpr Vec3() = default;
  constexpr Vec3(T x_, T y_, T z_) : x(x_), y(y_), z(z_) {}
  // Converts from another scalar type (double -> Jet), so directions known as data can enter
  // an autodiff evaluation.
  template <typename U>
  constexpr explicit Vec3(const Vec3<U>& v) : x(T(v.x)), y(T(v.y)), z(T(v.z)) {}

  constexpr Vec3 operator+(const Vec3& b) const { return {x + b.x, y + b.y, z + b.z}; }
  constexpr Vec3 operator-(const Vec3& b) const { return {x - b.x, y - b.y, z - b.z}; }
  constexpr Vec3 operator-() const { return {-x, -y, -z}; }
  constexpr Vec3 operator*(const T& s) const { return {x * s, y * s, z * s}; }
  constexpr Vec3 operator/(const T& s) const { return {x / s, y / s, z / s}; }
};

template <typename T>
constexpr Vec3<T> operator*(const T& s, const Vec3<T>& v) {
  return v * s;
}

template <typename T>
constexpr T Dot(const Vec3<T>& a, const Vec3<T>& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}

template <typename T>
T AbsDot(const Vec3<T>& a, const Vec3<T>& b) {
  using std::abs;
  return abs(Dot(a, b));
}

template <typename T>
constexpr Vec3<T> Cross(const Vec3<T>& a, const Vec3<T>& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

template <typename T>
T LengthSquared(const Vec3<T>& v) {
  return Dot(v, v);
}

template <typename T>
T Length(const Vec3<T>& v) {
  using std::sqrt;
  return sqrt(Dot(v, v));
}

// Precondition: v is not the zero vector (callers check degenerate half vectors first).
template <typename T>
Vec3<T> Normalize(const Vec3<T>& v) {
  return v / Length(v);
}

// Spherical functions of a unit direction in the shading frame (n = +z).
template <typename T>
constexpr T CosTheta(const Vec3<T>& w) {
  return w.z;
}
template <typename T>
T AbsCosTheta(const Vec3<T>& w) {
  using std::abs;
  return abs(w.z);
}
template <typename T>
constexpr T Cos2Theta(const Vec3<T>& w) {
  return w.z * w.z;
}
template <typename T>
T Sin2Theta(const Vec3<T>& w) {
  // From the components rather than 1 - cos^2: exact near the normal, where cos^2 rounds to 1.
  return w.x * w.x + w.y * w.y;
}
// tan^2 theta; +inf exactly at the horizon (callers test CosTheta == 0 first where it matters).
template <typename T>
T Tan2Theta(const Vec3<T>& w) {
  return Sin2Theta(w) / Cos2Theta(w);
}

template <typename T>
constexpr bool SameHemisphere(const Vec3<T>& a, const Vec3<T>& b) {
  return a.z * b.z > T(0);
}

// Unit direction from polar angle (via sin and cos) and azimuth phi.
template <typename T>
Vec3<T> SphericalDirection(const T& sinTheta, const T& cosTheta, const T& phi) {
  using std::cos;
  using std::sin;
  return {sinTheta * cos(phi), sinTheta * sin(phi), cosTheta};
}

// Direction at polar angle theta (radians, from +z) in the x-z plane (phi = 0), or its mirror
// (phi = pi) for negative theta: how the bench's in-plane sweeps are parameterised.
template <typename T>
Vec3<T> DirectionInPlane(const T& theta) {
  using std::cos;
  using std::sin;
  return {sin(theta), T(0), cos(theta)};
}

// A flat point in [0,1)^2: the two uniform variates of the sampling routines (xi_1, xi_2).
struct Point2 {
  double x = 0, y = 0;
};

}  // namespace gonio::optics
