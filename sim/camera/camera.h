// The simulated cooled CCD as a real GenICam device: Aravis's fake GigE Vision camera serves the
// project's own GenICam XML (gonio-cooled-ccd.xml) on 127.0.0.1, and a firmware thread plays the
// camera behind its registers - the cooler, exposure timing and the scene's frames.
//
// Timing (as a CCD): an exposure starts on TriggerSoftware (TriggerMode On) or right after the
// previous readout (Off); the frame leaves after exposure + readout of simulated time; the stage
// angles at the start and end of the exposure decide what it sees (their mean image, if the
// stages moved). AcquisitionStatus (ExposureActive) falls when the exposure ends, in the step
// that takes the end angles, so motion during the readout does not reach the frame. The firmware
// renders the frame before releasing it, so Aravis's single protocol thread never blocks on
// rendering and keeps answering GVCP.
//
// Registers (docs/camera_features.md): Aravis's fake camera implements those below 0x400; the
// firmware owns 0x400 and up. Network rules (docs/design.md): loopback only, GVCP port 3956, so
// one GigE camera per machine (tests take the CTest RESOURCE_LOCK "gvcp").
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <thread>

#include <opencv2/core.hpp>

#include "common/result.h"
#include "sim/camera/cooler.h"
#include "sim/camera/sensor.h"
#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/scene/lamp.h"
#include "sim/scene/scene.h"

struct _ArvGvFakeCamera;
struct _ArvFakeCamera;
struct _ArvBuffer;

namespace gonio::sim {

namespace camera_reg {  // the firmware's registers (32-bit, big-endian)
inline constexpr std::uint32_t kDeviceTemperature = 0x400;  // signed, milli-deg C (RO)
inline constexpr std::uint32_t kTriggerMode = 0x404;        // 0 free running, 1 triggered
// GigE Vision bootstrap registers (GigE Vision 2.0, section 28): the heartbeat timeout in ms
// and the control channel privilege.
inline constexpr std::uint32_t kHeartbeatTimeout = 0x0938;
inline constexpr std::uint32_t kControlChannelPrivilege = 0x0A00;
inline constexpr std::uint32_t kTriggerSoftware = 0x408;   // write 1: start an exposure
inline constexpr std::uint32_t kCoolerMode = 0x40c;        // 0 off, 1 on
inline constexpr std::uint32_t kSetpoint = 0x410;          // signed, milli-deg C
inline constexpr std::uint32_t kSetpointActivate = 0x414;  // write 1: apply kSetpoint
inline constexpr std::uint32_t kCoolingPower = 0x418;      // milli-percent (RO)
inline constexpr std::uint32_t kBlackLevel = 0x41c;        // ADU
inline constexpr std::uint32_t kShutter = 0x428;           // 0 open, 1 closed (dark frames)
inline constexpr std::uint32_t kExposureActive = 0x42c;    // 1 while integrating (RO)
inline constexpr std::uint32_t kStatusSelector = 0x430;    // 6: ExposureActive (the only one)
inline constexpr std::uint32_t kAcquisitionAbort = 0x434;  // write 1: drop the frame in hand
// GigE Vision bootstrap timestamp registers (GigE Vision 2.0, section 28): the tick frequency
// (64 bits, high word first), Timestamp Control (write bit 30, value 2: latch the counter; bit 31,
// value 1: reset it to 0) and the latched value (64 bits, high word first). Frames carry the
// counter at the start of their exposure in their GVSP leader.
inline constexpr std::uint32_t kTimestampTickFrequencyHigh = 0x093C;
inline constexpr std::uint32_t kTimestampTickFrequencyLow = 0x0940;
inline constexpr std::uint32_t kTimestampControl = 0x0944;
inline constexpr std::uint32_t kTimestampValueHigh = 0x0948;
inline constexpr std::uint32_t kTimestampValueLow = 0x094C;
// GigE Vision bootstrap strings (GigE Vision 2.0, section 28, table 28-1): 32 bytes each,
// NUL-padded; a client's device list shows them.
inline constexpr std::uint32_t kManufacturerName = 0x0048;
inline constexpr std::uint32_t kModelName = 0x0068;
inline constexpr std::uint32_t kDeviceVersion = 0x0088;
inline constexpr std::size_t kBootstrapStringBytes = 32;
}  // namespace camera_reg

// The genicam file installed beside the sources (compiled-in path; overridable).
std::string DefaultCameraGenicamPath();

struct CameraOptions {
  std::string serial = "GONIO-CCD-1";
  std::string genicam_path = DefaultCameraGenicamPath();
  std::string address = "127.0.0.1";  // GigE only; must be a loopback address
  ImageRegion sensor;                 // sensor size and object-side pixel pitch
  SensorOptions sensor_options;
  CoolerOptions cooler;
  std::uint64_t seed = 1;
  double poll_s = 0.001;  // real time between firmware steps
  // Where to append one CSV line per frame with what it saw (the stages' true angles at the
  // exposure's start and end, the shutter, the lamp's mean over the exposure), to check the
  // read-backs and the budget against; empty: none (gonio-sim --truth-log).
  std::string truth_log;
};

// What the stages show the camera: the stage angles now.
using AnglesSource = std::function<StageAngles()>;

class SimulatedCamera {
 public:
  // Starts the GigE Vision camera on options.address (GVCP port 3956). Errors: the address is not
  // loopback (InvalidArgument), the genicam file is missing, or the port is taken (Io). The
  // scene, the clock, the lamp and the fault plan (may be null) must outlive the camera.
  // Faults: frame_drop, frame_incomplete and frame_late (opportunity: each frame at the end of
  // its readout; an incomplete frame leaves with 30 % of its GVSP packets lost, which the client
  // sees as a buffer with missing packets; a late one leaves duration_s simulated seconds after
  // its readout, stamped with its exposure's start as ever), latch_slow (opportunity: each
  // timestamp latch written; it is taken duration_s simulated seconds later), cooler_fail
  // (opportunity: each firmware step, so at_time_s).
  static Result<std::unique_ptr<SimulatedCamera>> StartGigE(const Clock& clock, const Scene& scene,
                                                            AnglesSource angles, const Lamp& lamp,
                                                            CameraOptions options = {},
                                                            FaultPlan* faults = nullptr);
  ~SimulatedCamera();  // stops the firmware, then the protocol thread
  SimulatedCamera(const SimulatedCamera&) = delete;
  SimulatedCamera& operator=(const SimulatedCamera&) = delete;

  // Fault injection (the fault plan): the next n exposures never leave the camera (the client
  // sees a frame timeout); the cooler stops cooling (the sensor drifts to ambient).
  void DropFrames(int n);
  // Drops the controller now, as the fault plan's control_lost does (CCP cleared).
  void DropControl();
  // A trigger the client did not send (a glitch on a trigger line): the camera exposes once more
  // at the next firmware step, or after the exposure in hand, and sends that frame too.
  void StrayTrigger();
  // The sensor is integrating (ExposureActive).
  bool Exposing() const;
  // GevHeartbeatTimeout as the client set it (bootstrap register 0x0938), in ms.
  std::uint32_t HeartbeatTimeoutMs() const;
  void FailCooler(bool failed);

  double SensorTemperature() const;
  const Sensor& sensor() const { return sensor_; }

 private:
  SimulatedCamera(const Clock& clock, const Scene& scene, AnglesSource angles, const Lamp& lamp,
                  CameraOptions options, FaultPlan* faults);
  static void Fill(_ArvBuffer* buffer, void* self, std::uint32_t exposure_us, std::uint32_t gain,
                   std::uint32_t pixel_format);
  void Firmware();
  void Step(double now);
  std::uint32_t Reg(std::uint32_t address) const;
  void SetReg(std::uint32_t address, std::uint32_t value);
  ImageRegion CurrentRegion() const;
  // The timestamp counter at clock time t: 1 GHz ticks since its last reset.
  std::uint64_t Ticks(double t) const;
  cv::Mat1w Shoot(const StageAngles& a0, const StageAngles& a1, double t0, double exposure_s);
  const cv::Mat1d& Rates(const StageAngles& a, const ImageRegion& region);

  const Clock& clock_;
  const Scene& scene_;
  AnglesSource angles_;
  const Lamp& lamp_;
  CameraOptions o_;
  FaultPlan* faults_;
  Sensor sensor_;

  _ArvGvFakeCamera* gv_ = nullptr;
  _ArvFakeCamera* fake_ = nullptr;  // owned by gv_

  mutable std::mutex mu_;  // guards everything below
  Cooler cooler_;
  std::mt19937_64 rng_;
  std::uint32_t cooler_mode_ = 0;
  bool exposing_ = false;
  bool acquiring_ = false;  // acquisition was running at the last firmware step
  double exposure_start_ = 0, exposure_s_ = 0;
  bool integrating_ = false;  // exposing_ and the exposure has not yet ended (readout follows)
  StageAngles angles_at_start_, angles_at_end_;
  std::optional<cv::Mat1w> ready_frame_;
  std::uint64_t ready_stamp_ = 0;  // ready_frame_'s exposure start, in timestamp ticks
  double ready_at_ = 0;            // when ready_frame_ may leave (frame_late holds it)
  bool handed_ = false;            // ready_frame_ is handed to the sender
  double timestamp_zero_ = 0;      // the clock's time when the counter was last reset
  bool latch_pending_ = false;     // a latch written and not yet taken (latch_slow)
  double latch_due_ = 0;           // when it is taken
  int drop_frames_ = 0;
  bool losing_packets_ = false;  // the last frame left with gvsp-lost-ratio raised
  struct CacheEntry {
    StageAngles angles;
    ImageRegion region;
    cv::Mat1d rates;
  };
  std::optional<CacheEntry> cache_;
  std::ofstream truth_log_;  // CameraOptions::truth_log, open when set

  std::atomic<bool> stop_{false};
  std::thread firmware_;
};

}  // namespace gonio::sim
