#include "backends/aravis_camera.h"

#include <arpa/inet.h>
#include <arv.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <thread>

namespace gonio::backends {

namespace {

constexpr guint64 kGevHeartbeatTimeout = 0x0938;  // GigE Vision bootstrap register, ms
// GigE Vision bootstrap timestamp registers (GigE Vision 2.0, section 28): tick frequency (64
// bits, high word first), Timestamp Control (write-only; bit 30, value 2, latches the counter)
// and the latched value (64 bits, high word first).
constexpr guint64 kGevTimestampTickFrequencyHigh = 0x093C;
constexpr guint64 kGevTimestampTickFrequencyLow = 0x0940;
constexpr guint64 kGevTimestampControl = 0x0944;
constexpr guint32 kGevTimestampLatch = 2;
constexpr guint64 kGevTimestampValueHigh = 0x0948;
constexpr guint64 kGevTimestampValueLow = 0x094C;

// Turns a GError into an Error (and frees it); nullptr: success.
Status Check(GError* e, const std::string& what, ErrorCode code = ErrorCode::kIo) {
  if (e == nullptr) return OkStatus();
  Error err{code, what + ": " + e->message};
  g_error_free(e);
  return err;
}

bool Has(ArvDevice* dev, const std::string& name) {
  return !name.empty() && arv_device_get_feature(dev, name.c_str()) != nullptr;
}

// Writes a number with the feature's own GenICam type (SFNC makes BlackLevel a Float; older
// cameras have an Integer): a Float as it is, an Integer rounded.
Status SetNumber(ArvDevice* dev, const std::string& name, double value) {
  ArvGcNode* node = arv_device_get_feature(dev, name.c_str());
  if (node == nullptr) return Error{ErrorCode::kInvalidArgument, name + ": no such feature"};
  GError* e = nullptr;
  if (ARV_IS_GC_FLOAT(node)) {
    arv_device_set_float_feature_value(dev, name.c_str(), value, &e);
  } else if (ARV_IS_GC_INTEGER(node)) {
    arv_device_set_integer_feature_value(dev, name.c_str(), std::llround(value), &e);
  } else {
    return Error{ErrorCode::kInvalidArgument, name + " is neither a Float nor an Integer feature"};
  }
  return Check(e, name);
}

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// GigE Vision 2.0 section 15 (GVCP): READREG_CMD (0x0080) of one register, answered by
// READREG_ACK (0x0081) with the same request id. The socket is connected, so that a camera whose
// host no longer listens on the GVCP port answers with ICMP port unreachable (ECONNREFUSED) at
// once; a silent one is given `tries` waits of `wait_ms`. Reads need no control privilege.
Status GvcpReadRegister(const std::string& ip, std::uint32_t address, int tries, int wait_ms) {
  constexpr std::uint16_t kGvcpPort = 3956, kReadReg = 0x0080, kReadRegAck = 0x0081;
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(kGvcpPort);
  if (::inet_pton(AF_INET, ip.c_str(), &to.sin_addr) != 1)
    return Error{ErrorCode::kInvalidArgument, "'" + ip + "' is not a numeric IPv4 address"};
  const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return Error{ErrorCode::kIo, std::string("GVCP socket: ") + std::strerror(errno)};
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  if (::connect(fd, reinterpret_cast<sockaddr*>(&to), sizeof to) != 0)
    return Error{ErrorCode::kNotConnected, std::string("GVCP: ") + std::strerror(errno)};
  static std::atomic<std::uint16_t> next_id{1};
  for (int attempt = 0; attempt < tries; ++attempt) {
    std::uint16_t id = next_id++;
    if (id == 0) id = next_id++;  // 0 is not a request id
    const std::uint8_t cmd[12] = {0x42,
                                  0x01,  // an acknowledge is asked for
                                  kReadReg >> 8,
                                  kReadReg & 0xff,
                                  0x00,
                                  0x04,  // payload: one address
                                  static_cast<std::uint8_t>(id >> 8),
                                  static_cast<std::uint8_t>(id & 0xff),
                                  static_cast<std::uint8_t>(address >> 24),
                                  static_cast<std::uint8_t>(address >> 16),
                                  static_cast<std::uint8_t>(address >> 8),
                                  static_cast<std::uint8_t>(address)};
    if (::send(fd, cmd, sizeof cmd, 0) < 0)
      return Error{ErrorCode::kNotConnected, std::string("GVCP: ") + std::strerror(errno)};
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(wait_ms);
    while (true) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                            deadline - std::chrono::steady_clock::now())
                            .count();
      if (left <= 0) break;
      pollfd p{fd, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left)) <= 0) break;
      std::uint8_t ack[64];
      const ssize_t n = ::recv(fd, ack, sizeof ack, 0);
      if (n < 0)  // ECONNREFUSED: nothing listens on the camera's GVCP port
        return Error{ErrorCode::kNotConnected, std::string("GVCP: ") + std::strerror(errno)};
      if (n >= 12 && ((ack[2] << 8) | ack[3]) == kReadRegAck && ((ack[6] << 8) | ack[7]) == id) {
        const int status = (ack[0] << 8) | ack[1];
        if (status != 0)
          return Error{ErrorCode::kDeviceFault,
                       "GVCP READREG answered status " + std::to_string(status)};
        return OkStatus();
      }
    }
  }
  return Error{ErrorCode::kTimeout, "no GVCP answer in " + std::to_string(tries) + " x " +
                                        std::to_string(wait_ms) + " ms"};
}

}  // namespace

Status AravisCamera::CheckLink() {
  if (s_.address.rfind("usb3:", 0) == 0) return OkStatus();
  if (Status s = GvcpReadRegister(s_.address, 0x0000, 2, 250); !s.ok())
    return Error{s.error().code, "camera " + s_.address + ": " + s.error().message};
  return OkStatus();
}

Result<std::unique_ptr<AravisCamera>> AravisCamera::Open(CameraSettings settings) {
  const std::string& a = settings.address;
  if (a.rfind("usb3:", 0) != 0) {
    in_addr ip{};
    if (inet_pton(AF_INET, a.c_str(), &ip) != 1)
      return InvalidArgument("camera address '" + a +
                             "' must be a numeric IPv4 address (GigE Vision, opened without "
                             "discovery) or usb3:<device id>");
  }
  if (settings.pixel_format != "Mono16" && settings.pixel_format != "Mono12")
    return InvalidArgument("camera pixel_format '" + settings.pixel_format +
                           "' is not Mono16 or Mono12");
  if (settings.binning < 1 || settings.buffers < 2 || settings.retries < 0)
    return InvalidArgument("camera binning must be >= 1, buffers >= 2, retries >= 0");
  std::unique_ptr<AravisCamera> c(new AravisCamera());
  c->s_ = std::move(settings);
  // A controller that died without releasing the camera (a killed process) keeps its control
  // privilege until the camera's heartbeat timeout, which that controller set (ours, from the
  // same config: heartbeat_timeout_s; 3 s on a camera left as it came): until then writes time
  // out. Keep trying for open_timeout_s, and at least that long and a little more.
  const double wait_s = std::max(c->s_.open_timeout_s, c->s_.heartbeat_timeout_s + 3);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(wait_s);
  for (;;) {
    Status s = c->Connect();
    if (s.ok()) return c;
    c->Disconnect();
    if (std::chrono::steady_clock::now() > deadline) return s.error();
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
}

AravisCamera::~AravisCamera() { Disconnect(); }

void AravisCamera::Disconnect() {
  if (camera_ != nullptr) {
    GError* e = nullptr;
    arv_camera_stop_acquisition(camera_, &e);
    if (e) g_error_free(e);
  }
  if (early_ != nullptr) g_object_unref(early_);  // popped, so no longer the stream's
  early_ = nullptr;
  exposed_ = false;
  stream_owner_.reset();  // frames still held unref their buffers themselves
  stream_ = nullptr;
  if (camera_ != nullptr) {
    g_signal_handlers_disconnect_by_data(arv_camera_get_device(camera_), this);
    g_object_unref(camera_);
  }
  camera_ = nullptr;
}

Status AravisCamera::Connect() {
  // A connection made halfway is undone: camera_ is null exactly when there is none.
  Status s = ConnectSteps();
  if (!s.ok()) Disconnect();
  return s;
}

Status AravisCamera::EnsureConnected() {
  if (camera_ != nullptr && stream_ != nullptr) return OkStatus();
  return Reopen("it was not connected (an earlier reopen failed)");
}

Status AravisCamera::ConnectSteps() {
  const std::string id = s_.address.rfind("usb3:", 0) == 0 ? s_.address.substr(5) : s_.address;
  GError* e = nullptr;
  camera_ = arv_camera_new(id.c_str(), &e);
  if (Status s = Check(e, "camera " + s_.address + " does not answer", ErrorCode::kNotConnected);
      !s.ok())
    return s;
  const char* vendor = arv_camera_get_vendor_name(camera_, nullptr);
  const char* model = arv_camera_get_model_name(camera_, nullptr);
  const char* serial = arv_camera_get_device_serial_number(camera_, nullptr);
  identity_ = std::string(vendor ? vendor : "?") + " " + (model ? model : "?") + " " +
              (serial ? serial : "?");
  if (Status s = Configure(); !s.ok()) return s;
  if (arv_camera_is_gv_device(camera_)) {
    // GigE Vision bootstrap register 0x0938, GevHeartbeatTimeout in ms (GigE Vision 2.0, table
    // 28-1): a camera that misses our heartbeat for that long drops our control and stops
    // streaming, which a loaded host has caused with the 3 s default (a clean-clone CI run).
    ArvDevice* dev = arv_camera_get_device(camera_);
    arv_device_write_register(dev, kGevHeartbeatTimeout,
                              static_cast<guint32>(std::lround(s_.heartbeat_timeout_s * 1000)), &e);
    if (Status s = Check(e, "camera " + s_.address + ": GevHeartbeatTimeout"); !s.ok()) return s;
    control_lost_ = false;
    // Frames are paired with triggers by the camera's clock where it can latch it: a frame
    // stamped before the latch taken just ahead of its trigger belongs to an earlier trigger
    // (issue notes, stops 25-27: on a loaded host a late frame left every later one a trigger
    // behind). A camera whose latch reads back unchanged is paired by order alone.
    guint32 fh = 0, fl = 0;
    arv_device_read_register(dev, kGevTimestampTickFrequencyHigh, &fh, &e);
    if (e == nullptr) arv_device_read_register(dev, kGevTimestampTickFrequencyLow, &fl, &e);
    g_clear_error(&e);
    const double hz = static_cast<double>((static_cast<std::uint64_t>(fh) << 32) | fl);
    stamps_ = false;
    if (hz > 0) {
      ns_per_tick_ = 1e9 / hz;
      auto before = ReadLatched();
      if (before.ok()) {
        latched_ticks_ = *before;
        stamps_ = LatchTimestamp(s_.latch_timeout_s).ok();
      }
    }
    // A camera that latched before and does not now is one whose firmware is late, not one
    // without a latch: reopened, it would be paired by order and take a late frame for the next
    // trigger's (a CI run under ASan: values 200 sigma off after a reopen). Not opened instead;
    // the next use tries again.
    if (had_stamps_ && !stamps_)
      return Error{ErrorCode::kTimeout, "camera " + s_.address +
                                            ": its timestamp latch, which pairs frames with "
                                            "triggers, did not answer within " +
                                            std::to_string(s_.latch_timeout_s) + " s"};
    had_stamps_ = had_stamps_ || stamps_;
    caps_.frame_stamps = stamps_;
    g_signal_connect(dev, "control-lost", G_CALLBACK(+[](ArvGvDevice*, gpointer self) {
                       static_cast<AravisCamera*>(self)->control_lost_ = true;
                     }),
                     this);
  }
  stream_ = arv_camera_create_stream(camera_, nullptr, nullptr, &e);
  if (Status s = Check(e, "camera " + s_.address + ": stream"); !s.ok()) return s;
  stream_owner_ = std::shared_ptr<_ArvStream>(stream_, [](_ArvStream* st) { g_object_unref(st); });
  const guint payload = arv_camera_get_payload(camera_, &e);
  if (Status s = Check(e, "camera payload size"); !s.ok()) return s;
  for (int k = 0; k < s_.buffers; ++k)
    arv_stream_push_buffer(stream_, arv_buffer_new(payload, nullptr));
  // A frame another client left in hand (a process killed mid-exposure) would arrive after our
  // first trigger and be taken for its frame, and every later one a frame late: abort it.
  (void)AbortFrame();
  arv_camera_start_acquisition(camera_, &e);
  if (Status s = Check(e, "camera " + s_.address + ": AcquisitionStart"); !s.ok()) return s;
  // A frame that was already on its way (sent when acquisition restarted) is let arrive and
  // drained here, not taken for the first trigger's (without timestamps, the only guard).
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  while (ArvBuffer* old = arv_stream_try_pop_buffer(stream_)) arv_stream_push_buffer(stream_, old);
  return OkStatus();
}

Status AravisCamera::Reopen(const std::string& cause) {
  {
    std::lock_guard lock(cause_mu_);
    reopen_cause_ = cause;
  }
  Disconnect();
  if (Status s = Connect(); !s.ok())
    return Error{ErrorCode::kNotConnected,
                 "camera " + s_.address + " lost and not reopened: " + s.error().message};
  ++reopens_;
  return SetExposure(exposure_s_);
}

std::string AravisCamera::LastReconnectionCause() const {
  std::lock_guard lock(cause_mu_);
  return reopen_cause_;
}

Status AravisCamera::Configure() {
  GError* e = nullptr;
  ArvDevice* dev = arv_camera_get_device(camera_);
  arv_camera_set_pixel_format_from_string(camera_, s_.pixel_format.c_str(), &e);
  if (Status s = Check(e, "PixelFormat " + s_.pixel_format); !s.ok()) return s;
  if (s_.binning > 1 || arv_camera_is_binning_available(camera_, nullptr)) {
    arv_camera_set_binning(camera_, s_.binning, s_.binning, &e);
    if (Status s = Check(e, "binning " + std::to_string(s_.binning)); !s.ok()) return s;
  }
  gint sw = 0, sh = 0;
  arv_camera_get_sensor_size(camera_, &sw, &sh, &e);
  if (Status s = Check(e, "SensorWidth/SensorHeight"); !s.ok()) return s;
  const int w = s_.roi_width > 0 ? s_.roi_width : sw / s_.binning;
  const int h = s_.roi_height > 0 ? s_.roi_height : sh / s_.binning;
  arv_camera_set_region(camera_, s_.roi_x, s_.roi_y, w, h, &e);
  if (Status s = Check(e, "region " + std::to_string(w) + "x" + std::to_string(h)); !s.ok())
    return s;
  arv_camera_set_gain(camera_, s_.gain_db, &e);
  if (Status s = Check(e, "Gain"); !s.ok()) return s;
  if (s_.black_level >= 0)
    if (Status s = SetNumber(dev, "BlackLevel", s_.black_level); !s.ok()) return s;
  arv_camera_set_acquisition_mode(camera_, ARV_ACQUISITION_MODE_CONTINUOUS, &e);
  if (Status s = Check(e, "AcquisitionMode"); !s.ok()) return s;
  arv_device_set_string_feature_value(dev, "TriggerSelector", "FrameStart", &e);
  if (e) g_clear_error(&e);  // optional on cameras with one trigger
  arv_device_set_string_feature_value(dev, "TriggerMode", "On", &e);
  if (Status s = Check(e, "TriggerMode On"); !s.ok()) return s;
  arv_device_set_string_feature_value(dev, "TriggerSource", "Software", &e);
  if (Status s = Check(e, "TriggerSource Software"); !s.ok()) return s;
  arv_camera_set_exposure_time(camera_, exposure_s_ * 1e6, &e);
  if (Status s = Check(e, "ExposureTime"); !s.ok()) return s;
  // The exposure's end, if the camera reports it: the selector is set once; a camera without the
  // features (or the selector's entry) reads out every frame before the stages move.
  const VendorFeatures& f = s_.features;
  caps_.temperature = Has(dev, f.temperature) &&
                      (f.temperature_selector.empty() || Has(dev, f.temperature_selector));
  caps_.cooler = Has(dev, f.control_mode) && Has(dev, f.setpoint);
  caps_.shutter = Has(dev, f.shutter);
  reports_end_ = Has(dev, f.status);
  if (reports_end_ && !f.status_selector.empty()) {
    arv_device_set_string_feature_value(dev, f.status_selector.c_str(),
                                        f.status_selector_value.c_str(), &e);
    if (e != nullptr) {
      g_clear_error(&e);
      reports_end_ = false;
    }
  }
  caps_.exposure_end = reports_end_;
  caps_.frame_stamps = false;  // until ConnectSteps finds a working latch (GigE Vision only)
  return OkStatus();
}

Status AravisCamera::SetExposure(double seconds) {
  if (!(seconds > 0)) return InvalidArgument("exposure must be > 0 s");
  if (Status c = EnsureConnected(); !c.ok()) return c;
  GError* e = nullptr;
  arv_camera_set_exposure_time(camera_, seconds * 1e6, &e);
  if (Status s = Check(e, "ExposureTime " + std::to_string(seconds) + " s"); !s.ok()) return s;
  exposure_s_ = arv_camera_get_exposure_time(camera_, nullptr) * 1e-6;
  return OkStatus();
}

Result<double> AravisCamera::Exposure() {
  if (Status c = EnsureConnected(); !c.ok()) return c.error();
  GError* e = nullptr;
  const double us = arv_camera_get_exposure_time(camera_, &e);
  if (Status s = Check(e, "ExposureTime"); !s.ok()) return s.error();
  return us * 1e-6;
}

Result<cv::Size> AravisCamera::ImageSize() {
  if (Status c = EnsureConnected(); !c.ok()) return c.error();
  GError* e = nullptr;
  gint x = 0, y = 0, w = 0, h = 0;
  arv_camera_get_region(camera_, &x, &y, &w, &h, &e);
  if (Status s = Check(e, "Width/Height"); !s.ok()) return s.error();
  return cv::Size(w, h);
}

_ArvBuffer* AravisCamera::PopFrame(double wait_s) {
  // A buffer handed back still CLEARED never received a packet: it holds no frame, not even a
  // failed one (Aravis occasionally returns one at once on a loaded machine). It goes back to the
  // pool and the wait for this trigger's frame goes on, so that frames and triggers stay paired.
  // A frame of an earlier trigger (Stale) goes back too; this trigger's exposure cannot have
  // begun before that one ended, so the wait starts again from its arrival.
  // The wait is sliced so that an interrupt (a daemon stopping) is seen within 50 ms.
  const auto span = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(wait_s));
  auto deadline = std::chrono::steady_clock::now() + span;
  while (true) {
    const double left =
        std::chrono::duration<double>(deadline - std::chrono::steady_clock::now()).count();
    if (left <= 0 || Interrupted()) return nullptr;
    ArvBuffer* b =
        arv_stream_timeout_pop_buffer(stream_, static_cast<guint64>(std::min(left, 0.05) * 1e6));
    if (b == nullptr) continue;
    if (Stale(b)) {
      ++stale_frames_;
      deadline = std::max(deadline, std::chrono::steady_clock::now() + span);
    } else if (arv_buffer_get_status(b) != ARV_BUFFER_STATUS_CLEARED) {
      return b;
    }
    arv_stream_push_buffer(stream_, b);
  }
}

Result<std::uint64_t> AravisCamera::ReadLatched() {
  // The value is two registers read one after the other: a latch landing between the reads
  // gives one word of each (seen on the simulator, whose firmware latches a moment after the
  // write). Read until two reads agree.
  ArvDevice* dev = arv_camera_get_device(camera_);
  auto once = [&]() -> Result<std::uint64_t> {
    GError* e = nullptr;
    guint32 hi = 0, lo = 0;
    arv_device_read_register(dev, kGevTimestampValueHigh, &hi, &e);
    if (e == nullptr) arv_device_read_register(dev, kGevTimestampValueLow, &lo, &e);
    if (Status s = Check(e, "camera " + s_.address + ": GevTimestampValue"); !s.ok())
      return s.error();
    return (static_cast<std::uint64_t>(hi) << 32) | lo;
  };
  auto last = once();
  for (int k = 0; k < 8 && last.ok(); ++k) {
    auto again = once();
    if (!again.ok() || *again == *last) return again;
    last = again;
  }
  if (!last.ok()) return last;
  return Error{ErrorCode::kIo, "camera " + s_.address + ": GevTimestampValue does not hold still"};
}

Status AravisCamera::LatchTimestamp(double wait_s) {
  ArvDevice* dev = arv_camera_get_device(camera_);
  GError* e = nullptr;
  arv_device_write_register(dev, kGevTimestampControl, kGevTimestampLatch, &e);
  if (Status s = Check(e, "camera " + s_.address + ": GevTimestampControl latch"); !s.ok())
    return s;
  const auto t0 = std::chrono::steady_clock::now();
  for (;;) {
    auto v = ReadLatched();
    if (!v.ok()) return v.error();
    if (*v != latched_ticks_) {
      latched_ticks_ = *v;
      not_before_ns_ = static_cast<std::uint64_t>(static_cast<double>(*v) * ns_per_tick_);
      return OkStatus();
    }
    if (Seconds(t0) > wait_s)
      return Error{ErrorCode::kTimeout, "camera " + s_.address +
                                            ": the timestamp latch did not change within " +
                                            std::to_string(wait_s) + " s"};
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
}

bool AravisCamera::Stale(ArvBuffer* b) const {
  return stamps_ && arv_buffer_get_status(b) == ARV_BUFFER_STATUS_SUCCESS &&
         arv_buffer_get_timestamp(b) < not_before_ns_;
}

Status AravisCamera::Trigger() {
  // After a reopen that failed there is no camera: not a pool without buffers.
  if (camera_ == nullptr || stream_ == nullptr)
    return Error{ErrorCode::kNotConnected, "camera " + s_.address + " is not connected"};
  // The camera dropped our control (a missed heartbeat): it sends nothing until we take it again.
  if (control_lost_.exchange(false))
    return Error{ErrorCode::kNotConnected,
                 "camera " + s_.address + ": control lost (heartbeat missed); reopening"};
  // Stale frames (from before this call) go back to the pool unread.
  if (early_ != nullptr) arv_stream_push_buffer(stream_, early_);
  early_ = nullptr;
  exposed_ = false;
  while (ArvBuffer* old = arv_stream_try_pop_buffer(stream_)) arv_stream_push_buffer(stream_, old);
  gint free_buffers = 0, filled = 0;
  arv_stream_get_n_buffers(stream_, &free_buffers, &filled);
  if (free_buffers == 0)
    return Error{ErrorCode::kBusy, "camera " + s_.address + ": all " + std::to_string(s_.buffers) +
                                       " frame buffers are held by earlier Frames; release one"};
  // The latch comes after everything this frame depends on (exposure, stage angles) is set, so
  // a frame exposed from it on sees them. A latch the camera does not take in time is a camera
  // that no longer answers as it did: the caller reopens it.
  if (stamps_)
    if (Status s = LatchTimestamp(s_.latch_timeout_s); !s.ok())
      return Error{ErrorCode::kIo, s.error().message};
  GError* e = nullptr;
  arv_camera_software_trigger(camera_, &e);
  return Check(e, "TriggerSoftware failed");
}

Result<Frame> AravisCamera::Wrap(ArvBuffer* b, int attempt) {
  if (arv_buffer_get_status(b) != ARV_BUFFER_STATUS_SUCCESS) {
    const int status = static_cast<int>(arv_buffer_get_status(b));
    arv_stream_push_buffer(stream_, b);
    return Error{ErrorCode::kDeviceFault,
                 "frame arrived incomplete (buffer status " + std::to_string(status) + ")"};
  }
  std::size_t size = 0;
  const void* data = arv_buffer_get_data(b, &size);
  const int w = arv_buffer_get_image_width(b), h = arv_buffer_get_image_height(b);
  if (data == nullptr || size < static_cast<std::size_t>(w) * h * 2) {
    arv_stream_push_buffer(stream_, b);
    return Error{ErrorCode::kProtocol, "camera frame smaller than its image"};
  }
  Frame f;
  f.exposure_s = exposure_s_;
  f.timestamp_ns = arv_buffer_get_timestamp(b);
  f.attempts = attempt;
  // The view shares the buffer; the last Frame copy gives it back to the pool (or frees it if
  // the stream has gone).
  std::weak_ptr<_ArvStream> owner = stream_owner_;
  f.hold = std::shared_ptr<void>(b, [owner](void* p) {
    auto* buf = static_cast<ArvBuffer*>(p);
    if (auto st = owner.lock()) {
      arv_stream_push_buffer(st.get(), buf);
    } else {
      g_object_unref(buf);
    }
  });
  f.image = cv::Mat1w(h, w, static_cast<std::uint16_t*>(const_cast<void*>(data)));
  return f;
}

bool AravisCamera::AbortFrame() {
  ArvDevice* dev = arv_camera_get_device(camera_);
  GError* e = nullptr;
  const bool has = arv_device_is_feature_available(dev, "AcquisitionAbort", &e);
  g_clear_error(&e);
  if (!has) return false;
  arv_device_execute_command(dev, "AcquisitionAbort", &e);
  const bool ok = e == nullptr;
  g_clear_error(&e);
  return ok;
}

Error AravisCamera::Abandon() {
  // SFNC's AcquisitionAbort ends the frame in hand at once, readout included; without it the
  // acquisition is stopped and started again below.
  GError* e = nullptr;
  if (AbortFrame()) {
    if (early_ != nullptr) arv_stream_push_buffer(stream_, early_);
    early_ = nullptr;
    exposed_ = false;
    return Error{ErrorCode::kAborted, "camera " + s_.address + ": exposure interrupted"};
  }
  arv_camera_stop_acquisition(camera_, &e);  // AcquisitionStop ends the exposure in progress
  g_clear_error(&e);
  // A camera that reports its exposure is watched until it has let go of it (briefly: a camera
  // that does not is restarted anyway; its frame, if one comes, is drained at the next trigger).
  if (reports_end_) {
    ArvDevice* dev = arv_camera_get_device(camera_);
    const auto t0 = std::chrono::steady_clock::now();
    while (Seconds(t0) < 0.25) {
      const bool active = arv_device_get_boolean_feature_value(dev, s_.features.status.c_str(), &e);
      g_clear_error(&e);
      if (!active) break;
      std::this_thread::sleep_for(std::chrono::duration<double>(s_.status_poll_s));
    }
  }
  arv_camera_start_acquisition(camera_, &e);  // ready for the next trigger (stale frames drained)
  g_clear_error(&e);
  if (early_ != nullptr) arv_stream_push_buffer(stream_, early_);
  early_ = nullptr;
  exposed_ = false;
  return Error{ErrorCode::kAborted, "camera " + s_.address + ": exposure interrupted"};
}

Result<Frame> AravisCamera::SnapOnce(int first_attempt, std::string* last_problem) {
  bool reopened = false;  // in this call: the frame says why
  for (int attempt = first_attempt; attempt <= first_attempt + s_.retries; ++attempt) {
    if (Interrupted()) return Abandon();
    if (Status t = Trigger(); !t.ok()) {
      if (t.error().code == ErrorCode::kBusy) return t.error();
      // The camera no longer answers, or dropped our control: reopen it once per attempt, then
      // trigger again in the same attempt (a reopen on the last one would otherwise end it).
      *last_problem = t.error().message;
      if (Status s = Reopen(t.error().message); !s.ok()) return s.error();
      reopened = true;
      if (Status again = Trigger(); !again.ok()) {
        if (again.error().code == ErrorCode::kBusy) return again.error();
        *last_problem = again.error().message;
        continue;
      }
    }
    const double wait_s = exposure_s_ + s_.frame_timeout_s;
    ArvBuffer* b = PopFrame(wait_s);
    if (b == nullptr && Interrupted()) return Abandon();
    if (b == nullptr) {
      *last_problem = "no frame within " + std::to_string(wait_s) + " s";
      continue;
    }
    auto f = Wrap(b, attempt);
    if (f.ok() && (attempt > 1 || reopened)) f->retried_because = *last_problem;
    if (f.ok() || f.error().code != ErrorCode::kDeviceFault) return f;
    *last_problem = f.error().message;
  }
  return Error{ErrorCode::kTimeout, *last_problem};
}

Status AravisCamera::Expose() {
  if (!reports_end_)
    return Error{ErrorCode::kFailedPrecondition,
                 "camera " + s_.address + " does not report the end of an exposure (no " +
                     s_.features.status + " feature): use Snap"};
  // Nothing has moved yet, so a trigger the camera did not take is tried once more after a
  // reopen.
  if (Status t = Trigger(); !t.ok()) {
    if (t.error().code == ErrorCode::kBusy) return t;
    if (Status s = Reopen(t.error().message); !s.ok()) return s;
    if (Status again = Trigger(); !again.ok()) return again;
  }
  exposed_ = true;
  stale_at_expose_ = stale_frames_;
  ArvDevice* dev = arv_camera_get_device(camera_);
  const auto t0 = std::chrono::steady_clock::now();
  const double limit_s = exposure_s_ + s_.frame_timeout_s;
  // The camera may not have begun when the status is first read: the end is "active, then not".
  // An exposure short enough to begin and end between two reads shows as its frame arriving.
  bool seen_active = false;
  for (;;) {
    if (Interrupted()) return Abandon();
    GError* e = nullptr;
    const bool active = arv_device_get_boolean_feature_value(dev, s_.features.status.c_str(), &e);
    if (Status s = Check(e, "camera " + s_.address + ": " + s_.features.status); !s.ok()) return s;
    if (active) {
      seen_active = true;
    } else if (seen_active) {
      return OkStatus();
    }
    if (ArvBuffer* b = arv_stream_try_pop_buffer(stream_)) {
      if (Stale(b)) {
        ++stale_frames_;
      } else if (arv_buffer_get_status(b) != ARV_BUFFER_STATUS_CLEARED) {
        early_ = b;
        return OkStatus();
      }
      arv_stream_push_buffer(stream_, b);  // the CLEARED quirk (PopFrame): not a frame
    }
    if (Seconds(t0) > limit_s)
      return Error{ErrorCode::kTimeout, "camera " + s_.address + ": the exposure of " +
                                            std::to_string(exposure_s_) + " s did not end within " +
                                            std::to_string(limit_s) + " s"};
    std::this_thread::sleep_for(std::chrono::duration<double>(s_.status_poll_s));
  }
}

Result<Frame> AravisCamera::Retrieve() {
  if (!exposed_)
    return Error{ErrorCode::kFailedPrecondition,
                 "camera " + s_.address + ": Retrieve without Expose"};
  exposed_ = false;
  ArvBuffer* b = early_ != nullptr ? early_ : PopFrame(s_.frame_timeout_s);
  early_ = nullptr;
  if (b == nullptr && Interrupted()) return Abandon();
  if (b == nullptr)
    return Error{ErrorCode::kTimeout, "camera " + s_.address + ": no frame within " +
                                          std::to_string(s_.frame_timeout_s) +
                                          " s of the exposure's end"};
  // An earlier trigger's frame arrived since Expose triggered: its exposure was in the camera,
  // and the end Expose saw may have been that one's. This frame may then have been exposed while
  // the stages moved; it is refused (the caller retakes it at its point), though its own stamp
  // says it is this trigger's.
  if (stale_frames_ != stale_at_expose_) {
    arv_stream_push_buffer(stream_, b);
    return Error{ErrorCode::kDeviceFault,
                 "camera " + s_.address +
                     ": a frame of an earlier trigger arrived during this exposure, so the "
                     "exposure's end that was seen may have been that frame's and the stages may "
                     "have moved during this one"};
  }
  auto f = Wrap(b, 1);
  if (!f.ok()) return Error{f.error().code, "camera " + s_.address + ": " + f.error().message};
  return f;
}

Result<Frame> AravisCamera::Snap() {
  std::string problem = "no frame";
  auto f = SnapOnce(1, &problem);
  // Every attempt timed out without a frame: a camera that was power-cycled answers its
  // registers but has forgotten its stream. Reopen it once and try again.
  const bool silent =
      !f.ok() && f.error().code == ErrorCode::kTimeout && problem.rfind("no frame", 0) == 0;
  if (silent) {
    const std::string seen = StreamCounters();  // the old stream's, before the reopen
    if (Status s = Reopen("every attempt silent: " + problem + " (" + seen + ")"); !s.ok())
      return s.error();
    f = SnapOnce(s_.retries + 2, &problem);
    if (f.ok()) f->retried_because += " (every attempt; then reopened; " + seen + ")";
  }
  if (f.ok() || f.error().code != ErrorCode::kTimeout) return f;
  const bool incomplete = problem.find("incomplete") != std::string::npos;
  return Error{incomplete ? ErrorCode::kDeviceFault : ErrorCode::kTimeout,
               "camera " + s_.address + ": " + problem + " (after " + std::to_string(s_.retries) +
                   " retries" + (silent ? " and a reopen)" : ")")};
}

std::string AravisCamera::StreamCounters() const {
  if (stream_ == nullptr) return "no stream";
  auto n = [&](const char* name) {
    return static_cast<unsigned long long>(arv_stream_get_info_uint64_by_name(stream_, name));
  };
  char text[256];
  std::snprintf(text, sizeof text,
                "the stream had completed %llu frames, received %llu packets and ignored %llu, "
                "missed %llu frames, %llu underruns, %llu timeouts",
                n("n_completed_buffers"), n("n_received_packets"), n("n_ignored_packets"),
                n("n_missing_frames"), n("n_underruns"), n("n_timeouts"));
  return text;
}

Result<double> AravisCamera::TemperatureC() {
  if (Status c = EnsureConnected(); !c.ok()) return c.error();
  ArvDevice* dev = arv_camera_get_device(camera_);
  GError* e = nullptr;
  const VendorFeatures& c = s_.features;
  if (!caps_.temperature)
    return Error{
        ErrorCode::kFailedPrecondition,
        "camera " + s_.address + " has no temperature sensor (no feature '" + c.temperature + "')"};
  if (!c.temperature_selector.empty()) {
    arv_device_set_string_feature_value(dev, c.temperature_selector.c_str(),
                                        c.temperature_selector_value.c_str(), &e);
    if (Status s = Check(e, c.temperature_selector); !s.ok()) return s.error();
  }
  const double t = arv_device_get_float_feature_value(dev, c.temperature.c_str(), &e);
  if (Status s = Check(e, c.temperature); !s.ok()) return s.error();
  return t;
}

Status AravisCamera::SetShutter(bool open) {
  const VendorFeatures& c = s_.features;
  if (Status st = EnsureConnected(); !st.ok()) return st;
  if (!caps_.shutter)
    return Error{ErrorCode::kFailedPrecondition, "camera " + s_.address +
                                                     " has no shutter (no feature '" + c.shutter +
                                                     "'): dark frames cannot be taken"};
  GError* e = nullptr;
  arv_device_set_string_feature_value(arv_camera_get_device(camera_), c.shutter.c_str(),
                                      (open ? c.shutter_open : c.shutter_closed).c_str(), &e);
  return Check(e, c.shutter);
}

Status AravisCamera::SetCooling(bool on, double setpoint_c) {
  const VendorFeatures& c = s_.features;
  if (Status st = EnsureConnected(); !st.ok()) return st;
  if (!caps_.cooler) return NoCooler();
  ArvDevice* dev = arv_camera_get_device(camera_);
  GError* e = nullptr;
  if (on) {
    if (Status s = SetNumber(dev, c.setpoint, setpoint_c); !s.ok()) return s;
    if (!c.setpoint_activate.empty()) {
      arv_device_execute_command(dev, c.setpoint_activate.c_str(), &e);
      if (Status s = Check(e, c.setpoint_activate); !s.ok()) return s;
    }
  }
  arv_device_set_string_feature_value(dev, c.control_mode.c_str(),
                                      (on ? c.control_on : c.control_off).c_str(), &e);
  return Check(e, c.control_mode);
}

Error AravisCamera::NoCooler() const {
  return Error{ErrorCode::kFailedPrecondition,
               "camera " + s_.address + " has no cooler (no feature '" + s_.features.control_mode +
                   "' with '" + s_.features.setpoint + "'): cooling waits are off"};
}

Status AravisCamera::CoolAndWait(const TemperatureWait& w) {
  if (Status st = EnsureConnected(); !st.ok()) return st;
  if (!caps_.cooler) return NoCooler();
  auto t_start = TemperatureC();
  if (!t_start.ok()) return t_start.error();
  const auto t0 = std::chrono::steady_clock::now();
  double within_since = -1, last = *t_start;
  for (;;) {
    if (w.cancel != nullptr && w.cancel->load())
      return Error{ErrorCode::kAborted, "cooling cancelled at " + std::to_string(last) + " C"};
    const double elapsed = Seconds(t0);
    // A ramp moves the setpoint from where the sensor started, at the rate asked.
    double sp = w.setpoint_c;
    if (w.ramp_c_per_min > 0) {
      const double step = w.ramp_c_per_min * elapsed / 60;
      sp = *t_start > w.setpoint_c ? std::max(w.setpoint_c, *t_start - step)
                                   : std::min(w.setpoint_c, *t_start + step);
    }
    if (Status s = SetCooling(true, sp); !s.ok()) return s;
    auto t = TemperatureC();
    if (!t.ok()) return t.error();
    last = *t;
    if (std::abs(last - w.setpoint_c) <= w.tolerance_c) {
      if (within_since < 0) within_since = elapsed;
      if (elapsed - within_since >= w.hold_s) return OkStatus();
    } else {
      within_since = -1;
    }
    if (elapsed > w.timeout_s)
      return Error{ErrorCode::kTimeout,
                   "sensor at " + std::to_string(last) + " C after " + std::to_string(elapsed) +
                       " s; setpoint " + std::to_string(w.setpoint_c) + " +- " +
                       std::to_string(w.tolerance_c) + " C not held for " +
                       std::to_string(w.hold_s) + " s (is the cooler working?)"};
    std::this_thread::sleep_for(std::chrono::duration<double>(w.poll_s));
  }
}

}  // namespace gonio::backends
