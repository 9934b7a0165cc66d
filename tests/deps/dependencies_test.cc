// The system libraries that scripts/install-deps.sh installs link and answer: a fresh machine that
// passes this has what the later folders (drivers, sim, acquisition, daemon) build on.
#include <arv.h>
#include <ceres/version.h>
#include <gtest/gtest.h>
#include <libusb.h>
#include <modbus.h>
#include <spdlog/version.h>
#include <sqlite3.h>

#include <toml++/toml.h>
#include <CLI/Version.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>

TEST(Dependencies, AravisIs08) {
  EXPECT_EQ(arv_get_major_version(), 0u);
  EXPECT_EQ(arv_get_minor_version(), 8u);
}

TEST(Dependencies, LibmodbusIs31) {
  EXPECT_EQ(libmodbus_version_major, 3u);
  EXPECT_EQ(libmodbus_version_minor, 1u);
}

TEST(Dependencies, LibusbIs10) {
  const libusb_version* v = libusb_get_version();
  ASSERT_NE(v, nullptr);
  EXPECT_EQ(v->major, 1);
  EXPECT_EQ(v->minor, 0);
}

TEST(Dependencies, OpenCvComputesAMean) {
  cv::Mat m(4, 4, CV_16UC1, cv::Scalar(1000));
  EXPECT_DOUBLE_EQ(cv::mean(m)[0], 1000.0);
}

TEST(Dependencies, SqliteOpensAnInMemoryDatabase) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(":memory:", &db), SQLITE_OK);
  EXPECT_EQ(
      sqlite3_exec(db, "CREATE TABLE t(x); INSERT INTO t VALUES (1);", nullptr, nullptr, nullptr),
      SQLITE_OK);
  sqlite3_close(db);
  EXPECT_GE(sqlite3_libversion_number(), 3031000);
}

TEST(Dependencies, CeresIsAtLeast21) {
  EXPECT_GE(CERES_VERSION_MAJOR * 100 + CERES_VERSION_MINOR, 201);
}

TEST(Dependencies, ConfigJsonCliAndLoggingLibrariesParse) {
  const auto table = toml::parse("a = 1.5");
  EXPECT_DOUBLE_EQ(table["a"].value_or(0.0), 1.5);
  EXPECT_EQ(nlohmann::json::parse(R"({"k": 2})")["k"].get<int>(), 2);
  EXPECT_GE(CLI11_VERSION_MAJOR, 2);
  EXPECT_GE(SPDLOG_VER_MAJOR, 1);
}
