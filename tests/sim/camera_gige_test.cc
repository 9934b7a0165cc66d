// The simulated cooled CCD seen through Aravis over GigE Vision on 127.0.0.1, as the real driver
// will see it: features by name, software trigger, frames. One GVCP server per machine: these
// tests hold the CTest resource lock "gvcp".
#include <arv.h>
#include <gtest/gtest.h>

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "devices/scpi_power_meter.h"
#include "optics/microfacet.h"
#include "sim/camera/camera.h"
#include "sim/monitor/power_meter.h"
#include "sim/truth/ground_truth.h"

namespace gonio::sim {
namespace {

struct ArvCameraDeleter {
  void operator()(ArvCamera* c) const { g_object_unref(c); }
};

class CameraGigETest : public ::testing::Test {
 protected:
  // Variants: a test fixture may drift the lamp or plan faults.
  virtual LampOptions LampOpts() {
    return LampOptions{.drift_per_hour = 0, .wander_amplitude = 0, .flicker_rms = 0};
  }
  virtual std::vector<FaultEvent> Faults() { return {}; }
  virtual void Adjust(CameraOptions&) {}

  void SetUp() override {
    lamp_ = std::make_unique<Lamp>(LampOpts());
    plan_ = std::make_unique<FaultPlan>(Faults(), 1);
    truth_ = MicrofacetTruth("beckmann", 0.344, 1.51);
    scene_ = std::make_unique<Scene>(BenchGeometry{}, truth_);
    CameraOptions o;
    o.sensor.sensor_width = o.sensor.sensor_height = 256;
    o.sensor.mm_per_pixel = 0.32;
    Adjust(o);
    auto cam = SimulatedCamera::StartGigE(
        clock_, *scene_, [this] { return angles_; }, *lamp_, o, plan_.get());
    ASSERT_TRUE(cam.ok()) << cam.error().message;
    camera_ = std::move(cam).value();
    GError* error = nullptr;
    client_.reset(arv_camera_new("127.0.0.1", &error));
    ASSERT_EQ(error, nullptr) << error->message;
  }

  // One triggered frame; returns its pixels (empty on timeout or a failed buffer, whose status
  // goes to *status; ARV_BUFFER_STATUS_UNKNOWN when no buffer came back at all). Callers that do
  // not ask for the status get one re-trigger after a failed buffer, as the driver does: on a
  // loaded machine Aravis occasionally hands back an unfilled buffer at once.
  cv::Mat1w Snap(double exposure_us, int timeout_ms = 3000, ArvBufferStatus* status = nullptr) {
    ArvBufferStatus st = ARV_BUFFER_STATUS_UNKNOWN;
    cv::Mat1w out = SnapOnce(exposure_us, timeout_ms, &st);
    if (status != nullptr) {
      *status = st;
    } else if (out.empty() && st != ARV_BUFFER_STATUS_UNKNOWN) {
      out = SnapOnce(exposure_us, timeout_ms, &st);
    }
    return out;
  }
  cv::Mat1w SnapOnce(double exposure_us, int timeout_ms, ArvBufferStatus* status) {
    GError* e = nullptr;
    arv_camera_set_exposure_time(client_.get(), exposure_us, &e);
    EXPECT_EQ(e, nullptr);
    arv_device_set_string_feature_value(arv_camera_get_device(client_.get()), "TriggerMode", "On",
                                        &e);
    EXPECT_EQ(e, nullptr);
    ArvStream* stream = arv_camera_create_stream(client_.get(), nullptr, nullptr, &e);
    EXPECT_EQ(e, nullptr);
    // Lost packets stay lost (the fake camera does not resend): an incomplete frame is reported.
    // A loaded machine delays packets on loopback too: a frame is given 0.5 s to complete (not
    // Aravis's 100 ms) and a socket buffer that holds a whole frame, so only the fault plan's
    // lost packets fail a frame. CI once saw a whole frame fail under load without these. With
    // resend off, a frame that lost packets is handed back only when this retention expires.
    g_object_set(stream, "packet-resend", ARV_GV_STREAM_PACKET_RESEND_NEVER, "frame-retention",
                 guint{500000}, "socket-buffer", ARV_GV_STREAM_SOCKET_BUFFER_AUTO, nullptr);
    const guint payload = arv_camera_get_payload(client_.get(), &e);
    for (int k = 0; k < 2; ++k) arv_stream_push_buffer(stream, arv_buffer_new(payload, nullptr));
    arv_camera_start_acquisition(client_.get(), &e);
    arv_camera_software_trigger(client_.get(), &e);
    EXPECT_EQ(e, nullptr);
    // A buffer still CLEARED received no packet (the Aravis quirk the driver also skips): it
    // goes back, and the wait for this trigger's frame goes on.
    const gint64 deadline = g_get_monotonic_time() + gint64{timeout_ms} * 1000;
    ArvBuffer* b = nullptr;
    while (true) {
      const gint64 left = deadline - g_get_monotonic_time();
      b = left > 0 ? arv_stream_timeout_pop_buffer(stream, static_cast<guint64>(left)) : nullptr;
      if (b == nullptr || arv_buffer_get_status(b) != ARV_BUFFER_STATUS_CLEARED) break;
      arv_stream_push_buffer(stream, b);
    }
    cv::Mat1w out;
    if (status != nullptr) *status = b ? arv_buffer_get_status(b) : ARV_BUFFER_STATUS_UNKNOWN;
    if (b != nullptr && arv_buffer_get_status(b) == ARV_BUFFER_STATUS_SUCCESS) {
      std::size_t size = 0;
      const void* data = arv_buffer_get_data(b, &size);
      out = cv::Mat1w(arv_buffer_get_image_height(b), arv_buffer_get_image_width(b),
                      const_cast<std::uint16_t*>(static_cast<const std::uint16_t*>(data)))
                .clone();
    }
    if (b != nullptr) g_object_unref(b);
    arv_camera_stop_acquisition(client_.get(), &e);
    g_object_unref(stream);
    return out;
  }

  ScaledClock clock_{20.0};
  std::unique_ptr<Lamp> lamp_;
  std::unique_ptr<FaultPlan> plan_;
  std::shared_ptr<const GroundTruth> truth_;
  std::unique_ptr<Scene> scene_;
  StageAngles angles_{0, 180, 0};
  std::unique_ptr<SimulatedCamera> camera_;
  std::unique_ptr<ArvCamera, ArvCameraDeleter> client_;
};

TEST_F(CameraGigETest, ServesItsOwnGenicamFeatures) {
  GError* e = nullptr;
  ArvDevice* dev = arv_camera_get_device(client_.get());
  EXPECT_STREQ(arv_camera_get_vendor_name(client_.get(), &e), "gonio");
  EXPECT_EQ(arv_device_get_integer_feature_value(dev, "SensorWidth", &e), 256);
  EXPECT_STREQ(arv_device_get_string_feature_value(dev, "PixelFormat", &e), "Mono16");
  const double t = arv_device_get_float_feature_value(dev, "DeviceTemperature", &e);
  EXPECT_EQ(e, nullptr);
  EXPECT_NEAR(t, 20.0, 0.5);  // the cooler starts off, at ambient
}

TEST_F(CameraGigETest, CoolerPullsTheSensorTowardTheSetpoint) {
  GError* e = nullptr;
  ArvDevice* dev = arv_camera_get_device(client_.get());
  arv_device_set_float_feature_value(dev, "SensorTemperatureSetpointValue", -10.0, &e);
  arv_device_execute_command(dev, "SensorTemperatureSetpointActivate", &e);
  arv_device_set_string_feature_value(dev, "SensorTemperatureControlMode", "On", &e);
  ASSERT_EQ(e, nullptr);
  const double t0 = clock_.Now();
  g_usleep(500000);  // 10 s of simulated time at 20x
  const double T = arv_device_get_float_feature_value(dev, "DeviceTemperature", &e);
  const double elapsed = clock_.Now() - t0;
  // First order from 20 C toward -10 C with tau = 60 s; the reading lags by at most a poll.
  const double expected = -10 + 30 * std::exp(-elapsed / 60);
  EXPECT_NEAR(T, expected, 0.6);
  EXPECT_GT(arv_device_get_float_feature_value(dev, "SensorCoolingPower", &e), 50);
}

TEST_F(CameraGigETest, FrameShowsTheGroundTruthInTheRectangle) {
  const double exposure_us = 200000;
  const double before = clock_.Now();
  cv::Mat1w frame = Snap(exposure_us);
  ASSERT_FALSE(frame.empty());
  // Exposure plus readout of simulated time passed before the frame arrived.
  EXPECT_GE(clock_.Now() - before, 0.2 + camera_->sensor().ReadoutSeconds(256 * 256));
  // A 1.3 mm square at the pole (4 x 4 pixels of 0.32 mm): it sees view directions within 0.4 deg
  // of the nominal one, which changes ground glass's value by < 0.1 % (docs/scene.md). A 3 x 10 mm
  // rectangle would read 3 % low at this geometry - the scene's, and the bench's, real bias.
  const cv::Rect rect(126, 126, 4, 4);
  const double mean = cv::mean(frame(rect))[0];
  const NominalGeometry g = Nominal(scene_->bench(), angles_);
  const SensorOptions& s = camera_->sensor().options();
  const double dark = camera_->sensor().DarkCurrent(camera_->SensorTemperature());  // cooler off
  const double e_per_s = scene_->options().electrons_per_s_per_unit * truth_->BtdfCos(g.l, g.v) +
                         scene_->options().stray_lens_e_per_s + dark;
  const double signal_e = e_per_s * 0.2;
  const double expected = s.bias_adu + signal_e / s.gain_e_per_adu;
  // 4 sigma of the mean of 16 pixels (shot and read noise), plus 0.2 % for the directions' spread.
  const double sigma_mean =
      std::sqrt(signal_e + s.read_noise_e * s.read_noise_e) / s.gain_e_per_adu / 4;
  EXPECT_NEAR(mean, expected, 4 * sigma_mean + 0.002 * (expected - s.bias_adu));
  // Outside the lens only stray light and bias remain.
  EXPECT_LT(cv::mean(frame(cv::Rect(0, 0, 8, 8)))[0], s.bias_adu + 10);
}

TEST_F(CameraGigETest, DroppedFrameTimesOutAtTheClient) {
  camera_->DropFrames(1);
  EXPECT_TRUE(Snap(10000, 800).empty());
  EXPECT_FALSE(Snap(10000).empty());  // the next one arrives
}

class CameraGigEFaults : public CameraGigETest {
 protected:
  std::vector<FaultEvent> Faults() override {
    return {OnOpportunity(FaultKind::kFrameIncomplete, 1), OnOpportunity(FaultKind::kFrameDrop, 3),
            AtTime(FaultKind::kCoolerFail, 0)};
  }
};

TEST_F(CameraGigEFaults, FaultPlanFramesArriveIncompleteOrNeverAndTheCoolerFails) {
  ArvBufferStatus status = ARV_BUFFER_STATUS_SUCCESS;
  // Frame 1: packets lost. Aravis hands the buffer back failed: missing packets, or (as here,
  // with resend off) its frame-retention time expired before the frame completed.
  EXPECT_TRUE(Snap(10000, 3000, &status).empty());  // the retention (0.5 s) and some to spare
  EXPECT_TRUE(status == ARV_BUFFER_STATUS_MISSING_PACKETS || status == ARV_BUFFER_STATUS_TIMEOUT)
      << status;
  EXPECT_FALSE(Snap(10000, 3000, &status).empty()) << status;  // frame 2: whole again
  // Frame 3 never leaves the camera: no frame comes (on a loaded machine Aravis may hand back
  // an unfilled buffer instead of none; either way no image).
  EXPECT_TRUE(Snap(10000, 800, &status).empty());
  EXPECT_NE(status, ARV_BUFFER_STATUS_SUCCESS);
  // The cooler failed at t = 0: switched on, it does not cool.
  GError* e = nullptr;
  ArvDevice* dev = arv_camera_get_device(client_.get());
  arv_device_set_string_feature_value(dev, "SensorTemperatureControlMode", "On", &e);
  ASSERT_EQ(e, nullptr);
  const double t0 = clock_.Now();
  while (clock_.Now() - t0 < 20) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_GT(arv_device_get_float_feature_value(dev, "DeviceTemperature", &e), 19.0);
  // The plan fired all three: the incomplete frame, the dropped one, the cooler.
  for (int i = 0; i < 100 && plan_->Fired().size() < 3; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_EQ(plan_->Fired().size(), 3u);
  EXPECT_EQ(plan_->Fired()[2].kind, FaultKind::kFrameDrop);
}

// The lamp's drift reaches both the camera's frames and the source monitor, in proportion: what
// monitor normalisation (#6) corrects. A lamp drifting 20 %/min makes it visible within seconds.
class CameraGigEDriftingLamp : public CameraGigETest {
 protected:
  LampOptions LampOpts() override {
    return LampOptions{.drift_per_hour = 12, .wander_amplitude = 0, .flicker_rms = 0};
  }
};

TEST_F(CameraGigEDriftingLamp, FramesAndMonitorFollowTheLampTogether) {
  SimulatedPowerMeter meter_device(clock_, *lamp_);
  devices::ScpiPowerMeter meter(meter_device);
  const cv::Rect rect(120, 120, 16, 16);
  const double bias = camera_->sensor().options().bias_adu;
  // The monitor read just before and just after each frame brackets the lamp during its
  // exposure (the drift is monotonic). How wide the bracket is depends on how long the render
  // and the transfer take on this machine, which is why it is read both sides.
  auto pa0 = meter.PowerW();
  const cv::Mat1w a = Snap(200000);
  auto pa1 = meter.PowerW();
  const double t0 = clock_.Now();
  while (clock_.Now() - t0 < 30) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  auto pb0 = meter.PowerW();
  const cv::Mat1w b = Snap(200000);
  auto pb1 = meter.PowerW();
  ASSERT_FALSE(a.empty());
  ASSERT_FALSE(b.empty());
  ASSERT_TRUE(pa0.ok() && pa1.ok() && pb0.ok() && pb1.ok());
  const double frame_ratio = (cv::mean(b(rect))[0] - bias) / (cv::mean(a(rect))[0] - bias);
  EXPECT_GT(*pb0 / *pa1, 1.08);  // 30 s at 20 %/min, at least
  // The frames' ratio lies within what the monitor saw around them (0.5 % for the frames'
  // shot noise and the meter's).
  EXPECT_GT(frame_ratio, *pb0 / *pa1 - 0.005);
  EXPECT_LT(frame_ratio, *pb1 / *pa0 + 0.005);
}

// gonio-sim --truth-log: one line per frame with the stages' true angles, the shutter and the
// lamp over the exposure, what bench/coverage/truth_angles.py sets against a run's read-backs.
class CameraGigETruthLog : public CameraGigETest {
 protected:
  void Adjust(CameraOptions& o) override {
    path_ = std::filesystem::temp_directory_path() /
            ("gonio_truth_log_" + std::to_string(::getpid()) + ".csv");
    std::filesystem::remove(path_);
    o.truth_log = path_.string();
  }
  void TearDown() override { std::filesystem::remove(path_); }
  std::filesystem::path path_;
};

TEST_F(CameraGigETruthLog, EachFrameLogsTheAnglesItSaw) {
  angles_ = StageAngles{30.0004, 160.6793, 0};
  ASSERT_FALSE(Snap(20000).empty());
  angles_ = StageAngles{59.9996, 144.8717, 0};
  ASSERT_FALSE(Snap(50000).empty());
  std::ifstream in(path_);
  std::string line;
  ASSERT_TRUE(std::getline(in, line));
  EXPECT_EQ(line,
            "t_s,exposure_s,shutter_closed,sample_deg,arm_deg,sample_deg_end,arm_deg_end,"
            "lamp_relative");
  std::vector<std::vector<double>> rows;
  while (std::getline(in, line)) {
    std::vector<double> row;
    std::stringstream ss(line);
    for (std::string cell; std::getline(ss, cell, ',');) row.push_back(std::stod(cell));
    ASSERT_EQ(row.size(), 8u) << line;
    rows.push_back(row);
  }
  // A stale trigger may add an early frame; the last two are the two snaps, in order.
  ASSERT_GE(rows.size(), 2u);
  const auto& a = rows[rows.size() - 2];
  const auto& b = rows.back();
  EXPECT_DOUBLE_EQ(a[3], 30.0004);
  EXPECT_DOUBLE_EQ(a[4], 160.6793);
  EXPECT_DOUBLE_EQ(a[6], 160.6793);
  EXPECT_NEAR(a[1], 0.02, 1e-9);
  EXPECT_EQ(a[2], 0);
  EXPECT_DOUBLE_EQ(b[3], 59.9996);
  EXPECT_DOUBLE_EQ(b[4], 144.8717);
  EXPECT_NEAR(b[1], 0.05, 1e-9);
  EXPECT_GT(b[0], a[0]);
  EXPECT_NEAR(b[7], 1.0, 1e-12);  // the lamp neither drifts nor flickers here
}

}  // namespace
}  // namespace gonio::sim
