// The CSV layer: every malformed file gets an error with file:line and the column.
#include "fitting/samples_csv.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>

#include <unistd.h>

#include "fitting/synthetic.h"

namespace gonio::fitting {
namespace {

std::string ErrorOf(const std::string& text) {
  auto r = ParseSamplesCsv(text, "s.csv");
  return r.ok() ? "" : r.error().message;
}

TEST(SamplesCsv, ParsesColumnsInAnyOrderWithCommentsAndOptionalAzimuths) {
  auto r = ParseSamplesCsv(
      "# a sweep\nsigma,value,theta_v_deg,theta_l_deg,note\n0.1,2.5,-20,30,x\n\n0.2,3,10,0,y\n",
      "s.csv");
  ASSERT_TRUE(r.ok()) << r.error().message;
  ASSERT_EQ(r->size(), 2u);
  EXPECT_EQ((*r)[0].line, 3);
  EXPECT_DOUBLE_EQ((*r)[0].value, 2.5);
  EXPECT_NEAR(ThetaViewDeg((*r)[0]), -20, 1e-12);
  EXPECT_NEAR(ThetaLightDeg((*r)[0]), 30, 1e-12);
  EXPECT_LT((*r)[0].view.z, 0);
}

TEST(SamplesCsv, MalformedFilesNameFileLineAndColumn) {
  EXPECT_EQ(ErrorOf("theta_l_deg,theta_v_deg,value\n0,1,2\n"),
            "s.csv:1: header has no column 'sigma' (required: theta_l_deg, theta_v_deg, value, "
            "sigma)");
  EXPECT_EQ(ErrorOf("theta_l_deg,theta_v_deg,value,sigma\n0,1,nan,1\n"),
            "s.csv:2: column 'value' is nan: values must be finite");
  EXPECT_EQ(ErrorOf("theta_l_deg,theta_v_deg,value,sigma\n0,1,2,1\n0,1,abc,1\n"),
            "s.csv:3: column 'value': 'abc' is not a number");
  EXPECT_EQ(ErrorOf("theta_l_deg,theta_v_deg,value,sigma\n0,1,2\n"),
            "s.csv:2: has 3 fields, the header has 4");
  EXPECT_EQ(ErrorOf("theta_l_deg,theta_v_deg,value,sigma\n95,1,2,1\n"),
            "s.csv:2: theta_l_deg must lie in (-90, 90)");
  EXPECT_EQ(ErrorOf("theta_l_deg,theta_v_deg,value,sigma,side\n0,1,2,1,sideways\n"),
            "s.csv:2: column 'side': 'sideways' is not transmission or reflection");
  EXPECT_EQ(ErrorOf(""), "s.csv: empty file (no header row)");
  EXPECT_EQ(ErrorOf("theta_l_deg,theta_v_deg,value,sigma\n"), "s.csv: no samples after the header");
}

// An export's dark set and its shared part of sigma (acquisition: dark_set, sigma_dark): read
// where the set is given, none where it is empty, and a part that is not below sigma is refused.
TEST(SamplesCsv, ReadsTheDarkSetAndRefusesASharedPartNotBelowSigma) {
  const std::string head = "theta_l_deg,theta_v_deg,value,sigma,dark_set,sigma_dark\n";
  auto r = ParseSamplesCsv(head + "0,1,2,0.5,7,0.25\n0,2,2,0.5,,0\n", "s.csv");
  ASSERT_TRUE(r.ok()) << r.error().message;
  ASSERT_EQ(r->size(), 2u);
  EXPECT_EQ((*r)[0].dark_set, 7);
  EXPECT_EQ((*r)[0].sigma_dark, 0.25);
  EXPECT_EQ((*r)[1].dark_set, -1);
  EXPECT_EQ((*r)[1].sigma_dark, 0);
  EXPECT_EQ(ErrorOf(head + "0,1,2,0.5,7,0.5\n"),
            "s.csv:2: column 'sigma_dark' is 0.500000: the dark set's part of sigma must lie in "
            "[0, sigma)");
  EXPECT_EQ(ErrorOf(head + "0,1,2,0.5,-3,0.1\n"),
            "s.csv:2: column 'dark_set': '-3' is not a set's id (an integer >= 0)");
  EXPECT_EQ(ErrorOf(head + "0,1,2,0.5,x,0.1\n"),
            "s.csv:2: column 'dark_set': 'x' is not a set's id (an integer >= 0)");
}

TEST(SamplesCsv, AReflectionRowViewsFromTheAirSideAndRoundTrips) {
  // theta_v from +n, positive away from the light: 30 deg at incidence 30 is the mirror direction.
  auto r = ParseSamplesCsv(
      "theta_l_deg,theta_v_deg,value,sigma,side\n30,30,2,1,reflection\n30,-20,2,1,reflection\n",
      "s.csv");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Sample& mirror = (*r)[0];
  EXPECT_TRUE(IsReflection(mirror));
  EXPECT_NEAR(mirror.view.x, -mirror.light.x, 1e-12);
  EXPECT_NEAR(mirror.view.z, mirror.light.z, 1e-12);
  EXPECT_NEAR(ThetaViewDeg((*r)[1]), -20, 1e-9);
  // Mixed sides in one file are read, and refused by the fit's validation naming the line.
  auto mixed = ParseSamplesCsv(
      "theta_l_deg,theta_v_deg,value,sigma,side\n0,1,2,1,transmission\n0,30,2,1,reflection\n",
      "s.csv");
  ASSERT_TRUE(mixed.ok());
  const Status v = ValidateSamples(*mixed, 1, "s.csv");
  ASSERT_FALSE(v.ok());
  EXPECT_NE(v.error().message.find("s.csv:3: a reflection sample among transmission ones"),
            std::string::npos)
      << v.error().message;
  // Written and read back, a synthetic reflection sweep keeps its directions.
  SyntheticSweep spec;
  spec.reflection = true;
  spec.theta_l_deg = {20, 60};
  spec.theta_v_step = 7;
  const auto samples = MakeSyntheticSweep(spec);
  const std::string path =
      (std::filesystem::temp_directory_path() / ("refl_" + std::to_string(::getpid()) + ".csv"))
          .string();
  ASSERT_TRUE(WriteSamplesCsv(path, samples).ok());
  auto back = ReadSamplesCsv(path);
  std::filesystem::remove(path);
  ASSERT_TRUE(back.ok()) << back.error().message;
  ASSERT_EQ(back->size(), samples.size());
  for (std::size_t k = 0; k < samples.size(); ++k) {
    EXPECT_NEAR(optics::Dot((*back)[k].view, samples[k].view), 1.0, 1e-12) << k;
    EXPECT_NEAR(optics::Dot((*back)[k].light, samples[k].light), 1.0, 1e-12) << k;
  }
}

TEST(SamplesCsv, ValidationNamesTheFileLine) {
  auto r = ParseSamplesCsv("theta_l_deg,theta_v_deg,value,sigma\n0,1,2,1\n0,2,-50,1\n0,3,2,1\n",
                           "s.csv");
  ASSERT_TRUE(r.ok());
  const Status s = ValidateSamples(*r, 2, "s.csv");
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().message.rfind("s.csv:3: value -50 is 50 sigma below zero", 0), 0u)
      << s.error().message;
}

TEST(SamplesCsv, WriteThenReadRoundTrips) {
  SyntheticSweep spec;
  spec.theta_l_deg = {0, 45};
  const auto samples = MakeSyntheticSweep(spec);
  const std::string path =
      (std::filesystem::temp_directory_path() / "gonio_samples_roundtrip.csv").string();
  ASSERT_TRUE(WriteSamplesCsv(path, samples).ok());
  auto back = ReadSamplesCsv(path);
  std::remove(path.c_str());
  ASSERT_TRUE(back.ok()) << back.error().message;
  ASSERT_EQ(back->size(), samples.size());
  for (std::size_t k = 0; k < samples.size(); ++k) {
    EXPECT_NEAR((*back)[k].value, samples[k].value, 1e-12 * std::abs(samples[k].value));
    EXPECT_NEAR(Dot((*back)[k].view, samples[k].view), 1.0, 1e-12);
    EXPECT_NEAR(Dot((*back)[k].light, samples[k].light), 1.0, 1e-12);
  }
}

TEST(SamplesCsv, MissingFileIsAnIoError) {
  auto r = ReadSamplesCsv("/nonexistent/gonio.csv");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kIo);
  EXPECT_NE(r.error().message.find("/nonexistent/gonio.csv"), std::string::npos);
}

}  // namespace
}  // namespace gonio::fitting
