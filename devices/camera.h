// The cooled camera as acquisition sees it: exposure, gain, black level, pixel format, region
// and binning, one software-triggered frame at a time, and the sensor's temperature and cooler.
// Frames are 16-bit images that view the transport's own buffer (no copy); the buffer returns to
// the camera when the last copy of the Frame goes.
#pragma once

#include <atomic>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "common/result.h"

namespace gonio::devices {

// Vendors name cooling and the shutter differently (no SFNC standard): the config maps the
// names. The cooling defaults are Allied Vision Goldeye's, which the simulated camera also uses.
struct VendorFeatures {
  std::string temperature_selector = "DeviceTemperatureSelector";  // empty: none
  std::string temperature_selector_value = "Sensor";
  std::string temperature = "DeviceTemperature";              // float; empty: no sensor
  std::string control_mode = "SensorTemperatureControlMode";  // enum; empty: no cooler
  std::string control_on = "On", control_off = "Off";
  std::string setpoint = "SensorTemperatureSetpointValue";
  std::string setpoint_activate = "SensorTemperatureSetpointActivate";  // command; empty: none
  // The shutter for dark frames (enum feature and its entries); empty: no shutter.
  std::string shutter = "ShutterMode";
  std::string shutter_open = "Open", shutter_closed = "Closed";
  // Whether the sensor is integrating (SFNC AcquisitionStatus with its selector at
  // ExposureActive), so the stages may move during readout; empty: the camera cannot say, and
  // every frame is read out before anything moves.
  std::string status_selector = "AcquisitionStatusSelector";
  std::string status_selector_value = "ExposureActive";
  std::string status = "AcquisitionStatus";
};

struct CameraSettings {
  // A numeric IPv4 address (GigE Vision, opened directly: no discovery broadcast), or
  // "usb3:<device id>" for USB3 Vision.
  std::string address = "127.0.0.1";
  std::string pixel_format = "Mono16";  // Mono16 | Mono12
  double gain_db = 0;
  int black_level = -1;  // ADU; < 0 leaves the camera's own
  int binning = 1;
  int roi_x = 0, roi_y = 0, roi_width = 0, roi_height = 0;  // 0 width/height: the full sensor
  int buffers = 4;
  double frame_timeout_s = 5;  // beyond the exposure time
  // GigE Vision: how long a timestamp latch (taken before each trigger, and once at open to learn
  // whether the camera has one) may take to appear. Not the frame's timeout: a latch waits for
  // the camera's firmware, which a busy camera (or a loaded host's simulator) takes late.
  double latch_timeout_s = 5;
  int retries = 2;  // failed or incomplete frames re-triggered, per Snap
  // Keep trying to open (a dead controller's control lingers for its heartbeat timeout): at
  // least heartbeat_timeout_s + 3 s.
  double open_timeout_s = 10;
  // GigE Vision: how long the camera keeps our control without hearing our heartbeat
  // (GevHeartbeatTimeout). Past it the camera drops control and stops streaming; the default
  // 3 s of cameras has been missed by a loaded host.
  double heartbeat_timeout_s = 10;
  double status_poll_s = 0.001;  // how often Expose() reads whether the exposure has ended
  // Where the sensor stops being linear (full well), raw ADU: acquisition keeps pixels below.
  double linear_limit_adu = 65535;
  VendorFeatures features;
};

// One frame: `image` views the transport buffer, kept alive by `hold`.
struct Frame {
  cv::Mat1w image;
  double exposure_s = 0;
  std::uint64_t timestamp_ns = 0;  // the camera's
  int attempts = 1;                // 1 + the retries this frame needed
  std::string retried_because;     // when attempts > 1: what the last failed attempt saw
  std::shared_ptr<void> hold;
};

struct TemperatureWait {
  double setpoint_c = -20;
  double tolerance_c = 0.5;
  double hold_s = 30;         // within tolerance continuously this long
  double timeout_s = 900;     // real seconds
  double ramp_c_per_min = 0;  // > 0: move the setpoint in steps at this rate (protects the sensor)
  double poll_s = 0.5;
  // When set, the wait ends with kAborted once this reads true (a daemon stopping or aborting).
  const std::atomic<bool>* cancel = nullptr;
};

// What a camera has besides frames. Each is optional: a camera without one is still a camera
// (info, snap), and what needs it says so (kFailedPrecondition naming the missing part).
struct CameraCapabilities {
  bool temperature = true;   // a sensor temperature to read (runs record it; the suspender)
  bool cooler = true;        // a cooler with a setpoint (cooling waits)
  bool shutter = true;       // a shutter to close for dark frames
  bool exposure_end = true;  // says when the sensor stops integrating (ReportsExposureEnd)
  // Its clock can be latched before a trigger, so a late frame of an earlier trigger is told
  // from this trigger's (StaleFrames); without it frames are paired with triggers by order.
  bool frame_stamps = true;
  // One line for logs: what is missing and what that turns off ("" when nothing is).
  std::string Missing() const {
    std::string m;
    auto add = [&](bool has, const char* what) {
      if (!has) m += (m.empty() ? "" : "; ") + std::string(what);
    };
    add(temperature,
        "no temperature sensor: the temperature suspender is off and runs are refused");
    add(cooler, "no cooler: cooling waits are off");
    add(shutter, "no shutter: dark frames cannot be taken, so runs are refused");
    add(exposure_end, "no exposure-end status: each frame is read out before the stages move");
    add(frame_stamps,
        "no timestamp latch: frames are paired with triggers by order, so a frame arriving after "
        "its wait could be taken for the next trigger's");
    return m;
  }
};

class Camera {
 public:
  virtual ~Camera() = default;
  // Fixed once the camera is open (its node map and the config's feature names).
  virtual CameraCapabilities Capabilities() const { return {}; }
  virtual std::string Identity() const = 0;  // "vendor model serial"
  virtual Status SetExposure(double seconds) = 0;
  virtual Result<double> Exposure() = 0;
  // The frames' size (region and binning applied).
  virtual Result<cv::Size> ImageSize() = 0;
  // One software-triggered frame at the current settings. Errors: kTimeout (no frame within the
  // exposure plus frame_timeout_s, after the retries), kDeviceFault (frames kept arriving
  // incomplete), kNotConnected (the camera left and could not be reopened).
  virtual Result<Frame> Snap() = 0;

  // A frame in two halves, so the stages can move while the sensor reads out (a quarter second
  // for a 512 x 512 CCD at 1 MHz). Expose() triggers one frame at the current settings and
  // returns once the sensor has stopped integrating: from then on the scene may change.
  // Retrieve() waits for that frame. Nothing is retried in between, since the scene may have
  // moved: a frame lost after Expose() is Retrieve()'s error (kTimeout, kDeviceFault,
  // kNotConnected), and the caller puts the scene back and takes it again with Snap().
  // Expose() is kFailedPrecondition when ReportsExposureEnd() is false: use Snap().
  virtual bool ReportsExposureEnd() const = 0;
  virtual Status Expose() = 0;
  virtual Result<Frame> Retrieve() = 0;
  // kFailedPrecondition without a temperature sensor (Capabilities).
  virtual Result<double> TemperatureC() = 0;
  // Closes (dark frames) or opens the shutter. kFailedPrecondition without one.
  virtual Status SetShutter(bool open) = 0;
  // kFailedPrecondition without a cooler (SetCooling and CoolAndWait).
  virtual Status SetCooling(bool on, double setpoint_c) = 0;
  // Turns the cooler on toward w.setpoint_c (ramped if asked) and waits until the sensor stays
  // within tolerance for hold_s. Errors: kTimeout naming the temperature reached; kAborted when
  // w.cancel was set.
  virtual Status CoolAndWait(const TemperatureWait& w) = 0;
  // How many times the camera has been opened again after it was lost (a power cycle): its
  // frames before and after a change of this count may not belong together.
  virtual int Reconnections() const { return 0; }
  // Why the camera was last opened again ("no frame within 5.1 s", "control lost ..."); empty
  // before the first. For the run's log: a reconnection that costs a point says what caused it.
  virtual std::string LastReconnectionCause() const { return {}; }
  // How many frames arrived that the camera's clock showed were exposed before the trigger
  // they would have answered (a late frame of an earlier trigger), and were refused. A count that
  // grows says the host or the link was slow enough to leave a frame behind; the frames kept are
  // still their triggers'. 0 for a camera that cannot tell.
  virtual int StaleFrames() const { return 0; }
  // Whether the camera answers on its control channel (GigE Vision: a register read over GVCP),
  // within about half a second; safe beside an exposure on another thread (the daemon's link
  // watch). Not a frame: a camera whose frames stopped but that answers is the frame timeout's.
  // OK for a camera that cannot tell.
  virtual Status CheckLink() { return OkStatus(); }

  // Once *flag reads true, a Snap, Expose or Retrieve in progress (or begun) ends within about
  // 0.1 s with kAborted: the exposure is stopped (AcquisitionStop) and the camera left ready for
  // the next trigger. Null (the default): nothing interrupts them. A daemon stopping sets it.
  void SetInterrupt(const std::atomic<bool>* flag) { interrupt_ = flag; }

 protected:
  bool Interrupted() const { return interrupt_ != nullptr && interrupt_->load(); }

 private:
  const std::atomic<bool>* interrupt_ = nullptr;
};

}  // namespace gonio::devices
