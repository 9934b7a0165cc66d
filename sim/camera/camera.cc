#include "sim/camera/camera.h"

#include <arpa/inet.h>
#include <arv.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>

namespace gonio::sim {

namespace {

// Registers of Aravis's fake camera (arvfakecamera.h) that the firmware uses.
constexpr std::uint32_t kFakeTriggerMode = ARV_FAKE_CAMERA_REGISTER_TRIGGER_MODE;
constexpr std::uint32_t kFakeTriggerSource = ARV_FAKE_CAMERA_REGISTER_TRIGGER_SOURCE;
constexpr std::uint32_t kFakeTriggerSoftware = ARV_FAKE_CAMERA_REGISTER_TRIGGER_SOFTWARE;
constexpr std::uint32_t kFakeAcquisition = ARV_FAKE_CAMERA_REGISTER_ACQUISITION;
constexpr std::uint32_t kFakeAcquisitionMode = ARV_FAKE_CAMERA_REGISTER_ACQUISITION_MODE;

bool SameAngles(const StageAngles& a, const StageAngles& b) {
  return a.sample_deg == b.sample_deg && a.arm_deg == b.arm_deg && a.azimuth_deg == b.azimuth_deg &&
         a.beam_blocked == b.beam_blocked;
}

void WriteString(ArvFakeCamera* fake, std::uint32_t address, std::size_t size,
                 const std::string& s) {
  std::string padded = s.substr(0, size - 1);
  padded.resize(size, '\0');
  arv_fake_camera_write_memory(fake, address, static_cast<guint32>(size), padded.data());
}

}  // namespace

std::string DefaultCameraGenicamPath() { return GONIO_SIM_CAMERA_XML; }

SimulatedCamera::SimulatedCamera(const Clock& clock, const Scene& scene, AnglesSource angles,
                                 const Lamp& lamp, CameraOptions options, FaultPlan* faults)
    : clock_(clock),
      scene_(scene),
      angles_(std::move(angles)),
      lamp_(lamp),
      o_(std::move(options)),
      faults_(faults),
      sensor_(o_.sensor.sensor_width, o_.sensor.sensor_height, o_.sensor_options, o_.seed),
      cooler_(o_.cooler, clock.Now()),
      rng_(o_.seed) {}

namespace {

// Whether a UDP socket is bound to the GVCP port (3956) on this address or on any address, from
// /proc/net/udp. GLib binds with SO_REUSEADDR, so a second fake camera would bind beside a first
// one that is still shutting down, and the clients' packets would go to either: it must wait.
bool GvcpPortBound(const std::string& address) {
  in_addr a{};
  if (inet_pton(AF_INET, address.c_str(), &a) != 1) return false;
  char mine[16], any[16];
  std::snprintf(mine, sizeof mine, "%08X:0F74", static_cast<unsigned>(a.s_addr));
  std::snprintf(any, sizeof any, "%08X:0F74", 0u);
  std::ifstream udp("/proc/net/udp");
  std::string line;
  std::getline(udp, line);  // header
  while (std::getline(udp, line)) {
    std::istringstream fields(line);
    std::string slot, local;
    fields >> slot >> local;
    if (local == mine || local == any) return true;
  }
  return false;
}

}  // namespace

Result<std::unique_ptr<SimulatedCamera>> SimulatedCamera::StartGigE(
    const Clock& clock, const Scene& scene, AnglesSource angles, const Lamp& lamp,
    CameraOptions options, FaultPlan* faults) {
  if (options.address.rfind("127.", 0) != 0) {
    return Error{ErrorCode::kInvalidArgument,
                 "simulated camera address " + options.address +
                     " is not a loopback address; the simulator serves on 127.0.0.1 only"};
  }
  if (!std::filesystem::exists(options.genicam_path)) {
    return Error{ErrorCode::kIo, "GenICam file not found: " + options.genicam_path};
  }
  // A simulator that has just been stopped may hold the port for a moment longer.
  for (int i = 0; GvcpPortBound(options.address); ++i) {
    if (i == 100)
      return Error{ErrorCode::kIo, "GigE Vision port " + options.address +
                                       ":3956 is taken by another process (another simulated "
                                       "camera, or arv-fake-gv-camera-0.8?)"};
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  std::unique_ptr<SimulatedCamera> cam(
      new SimulatedCamera(clock, scene, std::move(angles), lamp, std::move(options), faults));
  const CameraOptions& o = cam->o_;
  if (!o.truth_log.empty()) {
    const bool fresh = !std::filesystem::exists(o.truth_log);
    cam->truth_log_.open(o.truth_log, std::ios::app);
    if (!cam->truth_log_) return Error{ErrorCode::kIo, "cannot write the truth log " + o.truth_log};
    if (fresh)
      cam->truth_log_ << "t_s,exposure_s,shutter_closed,sample_deg,arm_deg,sample_deg_end,"
                         "arm_deg_end,lamp_relative\n";
    cam->truth_log_ << std::setprecision(12);
  }
  cam->gv_ =
      arv_gv_fake_camera_new_full(o.address.c_str(), o.serial.c_str(), o.genicam_path.c_str());
  if (cam->gv_ == nullptr || !arv_gv_fake_camera_is_running(cam->gv_)) {
    return Error{ErrorCode::kIo, "cannot serve GigE Vision on " + o.address +
                                     ":3956 (is another simulated camera or "
                                     "arv-fake-gv-camera-0.8 running?)"};
  }
  ArvFakeCamera* fake = arv_gv_fake_camera_get_fake_camera(cam->gv_);
  cam->fake_ = fake;
  WriteString(fake, camera_reg::kManufacturerName, camera_reg::kBootstrapStringBytes, "gonio");
  WriteString(fake, camera_reg::kModelName, camera_reg::kBootstrapStringBytes,
              "CooledCCD (simulated)");
  WriteString(fake, camera_reg::kDeviceVersion, camera_reg::kBootstrapStringBytes, "gonio-sim 1");
  const ImageRegion& s = o.sensor;
  cam->SetReg(ARV_FAKE_CAMERA_REGISTER_SENSOR_WIDTH, s.sensor_width);
  cam->SetReg(ARV_FAKE_CAMERA_REGISTER_SENSOR_HEIGHT, s.sensor_height);
  cam->SetReg(ARV_FAKE_CAMERA_REGISTER_WIDTH, s.sensor_width);
  cam->SetReg(ARV_FAKE_CAMERA_REGISTER_HEIGHT, s.sensor_height);
  cam->SetReg(ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT, ARV_PIXEL_FORMAT_MONO_16);
  cam->SetReg(ARV_FAKE_CAMERA_REGISTER_EXPOSURE_TIME_US, 100000);
  cam->SetReg(ARV_FAKE_CAMERA_REGISTER_GAIN_RAW, 0);
  cam->SetReg(camera_reg::kTimestampTickFrequencyHigh, 0);
  cam->SetReg(camera_reg::kTimestampTickFrequencyLow, 1000000000);
  // The fake camera itself always waits for a software trigger: the firmware gives it one when
  // a frame is ready, whatever the client's TriggerMode. It looks for one at this rate. Its thread
  // (arvgvfakecamera.c) polls its sockets for the whole milliseconds left to the next look and
  // spins (poll with timeout 0) through the last partial one: at 1000 Hz it spun all the time,
  // half of gonio-sim's CPU by perf. At 100 Hz it sleeps 9 ms of 10, and a ready frame leaves at
  // most 10 ms (real) later.
  cam->SetReg(kFakeTriggerMode, 1);
  cam->SetReg(kFakeTriggerSource, 1);
  constexpr double kTriggerLookHz = 100;
  arv_fake_camera_set_trigger_frequency(fake, kTriggerLookHz);
  cam->SetReg(camera_reg::kTriggerMode, 0);
  cam->SetReg(camera_reg::kBlackLevel, static_cast<std::uint32_t>(o.sensor_options.bias_adu));
  cam->SetReg(camera_reg::kSetpoint, static_cast<std::uint32_t>(-20000));
  cam->SetReg(camera_reg::kStatusSelector, 6);
  cam->Step(clock.Now());
  arv_fake_camera_set_fill_pattern(fake, &SimulatedCamera::Fill, cam.get());
  cam->firmware_ = std::thread([c = cam.get()] { c->Firmware(); });
  return cam;
}

SimulatedCamera::~SimulatedCamera() {
  // The firmware reads the fake camera's registers: stop it before the camera goes.
  stop_ = true;
  if (firmware_.joinable()) firmware_.join();
  if (gv_ != nullptr) g_object_unref(gv_);  // joins Aravis's thread: no Fill after this
}

std::uint32_t SimulatedCamera::Reg(std::uint32_t address) const {
  guint32 v = 0;
  arv_fake_camera_read_register(fake_, address, &v);
  return v;
}

void SimulatedCamera::SetReg(std::uint32_t address, std::uint32_t value) {
  arv_fake_camera_write_register(fake_, address, value);
}

std::uint32_t SimulatedCamera::HeartbeatTimeoutMs() const {
  return Reg(camera_reg::kHeartbeatTimeout);
}

void SimulatedCamera::DropControl() {
  std::lock_guard lock(mu_);
  SetReg(camera_reg::kControlChannelPrivilege, 0);
}

void SimulatedCamera::StrayTrigger() {
  std::lock_guard lock(mu_);
  SetReg(camera_reg::kTriggerSoftware, 1);
}

bool SimulatedCamera::Exposing() const {
  std::lock_guard lock(mu_);
  return integrating_;
}

std::uint64_t SimulatedCamera::Ticks(double t) const {
  return static_cast<std::uint64_t>(std::llround(std::max(0.0, t - timestamp_zero_) * 1e9));
}

void SimulatedCamera::DropFrames(int n) {
  std::lock_guard lock(mu_);
  drop_frames_ += n;
}

void SimulatedCamera::FailCooler(bool failed) {
  std::lock_guard lock(mu_);
  cooler_.SetFailed(failed, clock_.Now());
}

double SimulatedCamera::SensorTemperature() const {
  std::lock_guard lock(mu_);
  return cooler_.Temperature(clock_.Now());
}

void SimulatedCamera::Firmware() {
  while (!stop_) {
    Step(clock_.Now());
    std::this_thread::sleep_for(std::chrono::duration<double>(o_.poll_s));
  }
}

ImageRegion SimulatedCamera::CurrentRegion() const {
  ImageRegion r = o_.sensor;
  r.offset_x = static_cast<int>(Reg(ARV_FAKE_CAMERA_REGISTER_X_OFFSET));
  r.offset_y = static_cast<int>(Reg(ARV_FAKE_CAMERA_REGISTER_Y_OFFSET));
  r.width = static_cast<int>(Reg(ARV_FAKE_CAMERA_REGISTER_WIDTH));
  r.height = static_cast<int>(Reg(ARV_FAKE_CAMERA_REGISTER_HEIGHT));
  r.binning_h = std::max(1, static_cast<int>(Reg(ARV_FAKE_CAMERA_REGISTER_BINNING_HORIZONTAL)));
  r.binning_v = std::max(1, static_cast<int>(Reg(ARV_FAKE_CAMERA_REGISTER_BINNING_VERTICAL)));
  return r;
}

const cv::Mat1d& SimulatedCamera::Rates(const StageAngles& a, const ImageRegion& region) {
  // One geometry is exposed many times (frames, dark-free repeats, auto-ranging): render once.
  if (!cache_ || !SameAngles(cache_->angles, a) || !(cache_->region == region)) {
    cache_ = CacheEntry{a, region, scene_.Render(a, region)};
  }
  return cache_->rates;
}

cv::Mat1w SimulatedCamera::Shoot(const StageAngles& a0, const StageAngles& a1, double t0,
                                 double exposure_s) {
  const ImageRegion region = CurrentRegion();
  cv::Mat1d rates = Rates(a0, region).clone();
  if (!SameAngles(a0, a1)) rates = 0.5 * (rates + Rates(a1, region));  // moved while exposing
  const double lamp = lamp_.MeanRelative(t0, t0 + exposure_s);
  rates *= lamp;
  if (Reg(camera_reg::kShutter) == 1) rates = 0.0;  // closed: a dark frame (dark current, bias)
  ExposureSettings s;
  s.exposure_s = exposure_s;
  s.gain_db = Reg(ARV_FAKE_CAMERA_REGISTER_GAIN_RAW) / 100.0;
  s.black_level_adu = Reg(camera_reg::kBlackLevel);
  s.temperature_c = cooler_.Temperature(t0 + 0.5 * exposure_s);
  s.depth = Reg(ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT) == ARV_PIXEL_FORMAT_MONO_12
                ? PixelDepth::k12
                : PixelDepth::k16;
  if (truth_log_.is_open()) {
    truth_log_ << t0 << ',' << exposure_s << ',' << Reg(camera_reg::kShutter) << ','
               << a0.sample_deg << ',' << a0.arm_deg << ',' << a1.sample_deg << ',' << a1.arm_deg
               << ',' << lamp << std::endl;
  }
  return sensor_.Expose(rates, region.offset_x, region.offset_y, region.binning_h, region.binning_v,
                        s, rng_);
}

void SimulatedCamera::Step(double now) {
  using namespace camera_reg;
  const StageAngles angles = angles_ ? angles_() : StageAngles{};
  std::lock_guard lock(mu_);
  if (MaybeFire(faults_, FaultKind::kCoolerFail, "camera", now)) cooler_.SetFailed(true, now);
  // GigE Vision: a camera whose controller missed its heartbeat clears the control channel
  // privilege (bootstrap register CCP, 0x0A00) and stops streaming until control is taken again.
  if (MaybeFire(faults_, FaultKind::kControlLost, "camera", now))
    SetReg(kControlChannelPrivilege, 0);
  // Cooler: mode on write, setpoint on Activate (as Goldeye-style cameras apply it).
  const std::uint32_t mode = Reg(kCoolerMode);
  if (mode != cooler_mode_) {
    cooler_mode_ = mode;
    cooler_.SetEnabled(mode == 1, now);
  }
  if (Reg(kSetpointActivate) != 0) {
    SetReg(kSetpointActivate, 0);
    cooler_.SetSetpoint(static_cast<std::int32_t>(Reg(kSetpoint)) / 1000.0, now);
  }
  SetReg(kDeviceTemperature, static_cast<std::uint32_t>(static_cast<std::int32_t>(
                                 std::lround(cooler_.Temperature(now) * 1000))));
  SetReg(kCoolingPower, static_cast<std::uint32_t>(std::lround(cooler_.PowerPercent(now) * 1000)));

  // Timestamp Control (GigE Vision bootstrap 0x0944): a write-only command the firmware clears.
  // Reset before latch when both are written; taken before the trigger below, so a frame whose
  // exposure starts in this step is stamped no earlier than a latch taken in it.
  if (const std::uint32_t ts = Reg(kTimestampControl); ts != 0) {
    SetReg(kTimestampControl, 0);
    if ((ts & 1u) != 0) timestamp_zero_ = now;
    // latch_slow: a camera busy elsewhere takes the latch late (a loaded host's simulator is
    // one); a latch written while one is pending is the same latch.
    if ((ts & 2u) != 0 && !latch_pending_) {
      const auto slow = MaybeFire(faults_, FaultKind::kLatchSlow, "camera", now);
      latch_pending_ = true;
      latch_due_ = now + (slow ? slow->duration_s : 0.0);
    }
  }
  if (latch_pending_ && now >= latch_due_) {
    latch_pending_ = false;
    const std::uint64_t t = Ticks(now);
    SetReg(kTimestampValueHigh, static_cast<std::uint32_t>(t >> 32));
    SetReg(kTimestampValueLow, static_cast<std::uint32_t>(t & 0xffffffffu));
  }

  // AcquisitionAbort (SFNC): a latch the firmware clears, so that an abort written between two
  // steps is never missed (a stop and a start written back to back can be). The exposure or
  // readout in hand ends and its frame is not sent; a trigger written after the abort stays.
  if (Reg(kAcquisitionAbort) != 0) {
    SetReg(kAcquisitionAbort, 0);
    exposing_ = integrating_ = false;
    SetReg(kExposureActive, 0);
    ready_frame_.reset();
    SetReg(kFakeTriggerSoftware, 0);  // a frame handed to the sender but not yet sent stays here
  }
  if (Reg(kFakeAcquisition) == 0) {
    // Just stopped: forget the exposure in progress. A trigger register left set is not cleared:
    // the client's GVCP writes do not take our lock, so a clear here can land after the client
    // has started again and triggered, and eat that trigger (a lost third frame, seen under CI
    // load). A stale trigger costs at most one early frame at the next start, which clients drain.
    if (acquiring_) {
      exposing_ = integrating_ = false;
      SetReg(kExposureActive, 0);
      ready_frame_.reset();
      // The sender's own trigger too: left set, it would send an empty frame at the next start
      // (after a client that stopped mid-frame, the next client's first frame).
      SetReg(kFakeTriggerSoftware, 0);
    }
    acquiring_ = false;
    return;
  }
  acquiring_ = true;
  if (ready_frame_) {  // held back (frame_late), or waiting for Aravis to send it
    if (!handed_ && now >= ready_at_) {
      SetReg(kFakeTriggerSoftware, 1);
      handed_ = true;
    }
    return;
  }
  if (!exposing_ && (Reg(kTriggerMode) == 0 || Reg(kTriggerSoftware) != 0)) {
    SetReg(kTriggerSoftware, 0);
    exposing_ = integrating_ = true;
    SetReg(kExposureActive, 1);
    exposure_start_ = now;
    exposure_s_ = Reg(ARV_FAKE_CAMERA_REGISTER_EXPOSURE_TIME_US) * 1e-6;
    angles_at_start_ = angles;
  }
  if (!exposing_) return;
  if (integrating_ && now >= exposure_start_ + exposure_s_) {
    // The exposure has ended: what the frame sees is settled before the status says so.
    integrating_ = false;
    angles_at_end_ = angles;
    SetReg(kExposureActive, 0);
  }
  const ImageRegion region = CurrentRegion();
  const double readout_s = sensor_.ReadoutSeconds(region.width * region.height);
  if (now < exposure_start_ + exposure_s_ + readout_s) return;
  exposing_ = false;
  if (MaybeFire(faults_, FaultKind::kFrameDrop, "camera", now)) ++drop_frames_;
  if (drop_frames_ > 0) {  // this frame is lost
    --drop_frames_;
    return;
  }
  // An incomplete frame: Aravis's fake camera drops that share of its GVSP packets. The previous
  // frame has long left when the next is ready, so the ratio is set per frame.
  const bool lose = MaybeFire(faults_, FaultKind::kFrameIncomplete, "camera", now).has_value();
  if (lose != losing_packets_) {
    g_object_set(gv_, "gvsp-lost-ratio", lose ? 0.3 : 0.0, nullptr);
    losing_packets_ = lose;
  }
  ready_frame_ = Shoot(angles_at_start_, angles_at_end_, exposure_start_, exposure_s_);
  ready_stamp_ = Ticks(exposure_start_);
  // A late frame (a stalled link or a busy camera) is held; a trigger written meanwhile waits
  // for it to leave, as the trigger of any frame in hand does.
  const auto late = MaybeFire(faults_, FaultKind::kFrameLate, "camera", now);
  ready_at_ = now + (late ? late->duration_s : 0.0);
  handed_ = now >= ready_at_;
  if (handed_) SetReg(kFakeTriggerSoftware, 1);
}

void SimulatedCamera::Fill(_ArvBuffer* buffer, void* self, std::uint32_t, std::uint32_t,
                           std::uint32_t) {
  auto* cam = static_cast<SimulatedCamera*>(self);
  std::size_t size = 0;
  auto* data = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, &size)));
  const int w = arv_buffer_get_image_width(buffer), h = arv_buffer_get_image_height(buffer);
  std::optional<cv::Mat1w> frame;
  std::uint64_t stamp = 0;
  {
    std::lock_guard lock(cam->mu_);
    frame.swap(cam->ready_frame_);
    stamp = cam->ready_stamp_;
    if (frame && cam->Reg(kFakeAcquisitionMode) == 2) cam->SetReg(kFakeAcquisition, 0);
  }
  // The GVSP leader's timestamp: the counter at the exposure's start (GigE Vision leaves the
  // instant to the device; exposure start is what a trigger can be checked against). A frame the
  // sender sends without one from the firmware (a stale trigger of the sender's own) is stamped 0.
  arv_buffer_set_timestamp(buffer, frame ? stamp : 0);
  if (data == nullptr || w <= 0 || h <= 0) return;
  // Aravis checked the buffer against the payload (w * h * 2 bytes) before calling.
  if (!frame || frame->cols != w || frame->rows != h) {
    std::memset(data, 0, static_cast<std::size_t>(w) * h * 2);  // region changed mid-exposure
  } else {
    for (int j = 0; j < h; ++j) std::memcpy(data + std::size_t(j) * w * 2, frame->ptr(j), w * 2);
  }
}

}  // namespace gonio::sim
