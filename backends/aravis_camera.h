// The camera over GenICam with Aravis 0.8: opened by numeric IP (GigE Vision) or USB3 Vision id,
// never by discovery (docs/design.md network rules); TriggerMode On with TriggerSoftware, a
// pool of stream buffers, failed or incomplete buffers re-triggered a bounded number of times, and
// a reopen when the camera has dropped off the network. Expose() watches SFNC's
// AcquisitionStatus (ExposureActive) when the camera has it, so readout can overlap motion. An
// exposure that begins and ends between two reads (under about a millisecond) looks the same as
// one not yet begun: Expose() then returns when its frame arrives, with nothing overlapped. An
// SFNC counter of exposure ends would remove that case; it is not used yet.
//
// Frames and triggers are paired by the camera's clock where the camera can latch it (GigE Vision
// bootstrap Timestamp Control): the driver latches the counter just before each trigger, after
// the exposure and the stages are set, and refuses a frame stamped earlier as an earlier
// trigger's, however late it arrives. Any stamping convention (exposure start, end or readout)
// keeps that rule sound: a frame stamped before the latch began before it. Elsewhere (USB3
// Vision, a camera whose latch reads back unchanged) frames are paired by order: stale frames
// drained before each trigger, and a reopen aborting what the camera holds.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <string>

#include "devices/camera.h"

struct _ArvCamera;
struct _ArvStream;
struct _ArvBuffer;

namespace gonio::backends {

using devices::Camera;
using devices::CameraSettings;
using devices::Frame;
using devices::TemperatureWait;
using devices::VendorFeatures;

class AravisCamera final : public Camera {
 public:
  static Result<std::unique_ptr<AravisCamera>> Open(CameraSettings settings);
  ~AravisCamera() override;

  std::string Identity() const override { return identity_; }
  Status SetExposure(double seconds) override;
  Result<double> Exposure() override;
  Result<cv::Size> ImageSize() override;
  Result<Frame> Snap() override;
  bool ReportsExposureEnd() const override { return reports_end_; }
  devices::CameraCapabilities Capabilities() const override { return caps_; }
  Status Expose() override;
  Result<Frame> Retrieve() override;
  Result<double> TemperatureC() override;
  Status SetShutter(bool open) override;
  Status SetCooling(bool on, double setpoint_c) override;
  Status CoolAndWait(const TemperatureWait& w) override;

  int reopens() const { return reopens_; }
  // Whether frames are checked against their trigger by the camera's timestamp (GigE Vision
  // cameras whose latch works), and how many frames the check has refused as exposed before
  // their trigger's latch (stale frames of an earlier trigger).
  bool ChecksFrameStamps() const { return stamps_; }
  int StaleFrames() const override { return stale_frames_; }
  int Reconnections() const override { return reopens_; }
  // GigE Vision: one READREG of the bootstrap Version register on a socket of its own (no
  // state shared with the acquisition thread). USB3 Vision: not checked (OK).
  Status CheckLink() override;
  std::string LastReconnectionCause() const override;

 private:
  AravisCamera() = default;
  Status Connect();  // camera, settings, stream; on failure nothing is left half-open
  Status ConnectSteps();
  // A camera lost earlier (a reopen that failed) is opened again before it is used.
  Status EnsureConnected();
  void Disconnect();
  // Disconnect, Connect, restore the exposure; counts reopens_ and keeps `cause` for the log.
  Status Reopen(const std::string& cause);
  Status Configure();
  // This trigger's frame (any status but CLEARED, not Stale) within wait_s of the trigger or of
  // the last stale frame, or null.
  _ArvBuffer* PopFrame(double wait_s);
  // GigE Vision timestamp latch (bootstrap 0x0944) and read of the latched value (0x0948/0x094C),
  // waiting up to wait_s for a value other than latched_ticks_ (a camera whose firmware latches
  // after the write's acknowledgement shows the old value for a moment). Sets latched_ticks_.
  Status LatchTimestamp(double wait_s);
  Result<std::uint64_t> ReadLatched();
  // Whether a buffer that arrived is one of an earlier trigger: stamped before this trigger's
  // latch (only with stamps_, and only complete frames: an incomplete one may have lost its
  // leader, and is retried anyway).
  bool Stale(_ArvBuffer* b) const;
  // Drains stale frames, latches the timestamp (stamps_) and triggers one. kBusy: every buffer is
  // held by earlier Frames; kIo: the trigger was not accepted (the camera may have gone).
  Status Trigger();
  // What the stream has seen since it was opened (Aravis's counters: frames completed, packets
  // received and ignored, missing frames, underruns, timeouts): said when every attempt was
  // silent, so that a log tells a camera that sent nothing from frames the stream threw away.
  std::string StreamCounters() const;
  // A popped buffer as a Frame; on error the buffer goes back to the pool. kDeviceFault: it
  // arrived incomplete; kProtocol: smaller than its image.
  Result<Frame> Wrap(_ArvBuffer* b, int attempt);
  // One trigger and its retries; kTimeout carries only the last problem (in *last_problem).
  Result<Frame> SnapOnce(int first_attempt, std::string* last_problem);
  // Interrupted (Camera::SetInterrupt): the exposure stopped and acquisition restarted; the
  // kAborted error to return.
  Error Abandon();
  // SFNC AcquisitionAbort when the camera has it: the frame in hand dropped. False without it.
  bool AbortFrame();
  Error NoCooler() const;

  CameraSettings s_;
  std::string identity_;
  _ArvCamera* camera_ = nullptr;
  _ArvStream* stream_ = nullptr;
  double exposure_s_ = 0.1;
  std::atomic<int> reopens_{0};  // read by the engine's readout thread (Reconnections)
  mutable std::mutex cause_mu_;  // the cause is read from that thread too
  std::string reopen_cause_;
  // Set by Aravis's heartbeat thread when the camera no longer grants us control (it stops
  // streaming then): the next trigger reopens at once instead of waiting out silent frames.
  std::atomic<bool> control_lost_{false};
  bool reports_end_ = false;  // the status feature exists (Connect)
  // Frame/trigger pairing by the camera's clock (Connect): the latch works; the latched counter,
  // its tick length, and the earliest frame stamp (ns, as Aravis reports it) this trigger accepts.
  bool stamps_ = false;
  bool had_stamps_ = false;  // an earlier connection latched: a reopen must too
  std::uint64_t latched_ticks_ = 0;
  double ns_per_tick_ = 1;
  std::uint64_t not_before_ns_ = 0;
  std::atomic<int> stale_frames_{0};
  int stale_at_expose_ = 0;           // stale_frames_ when Expose triggered (Retrieve compares)
  devices::CameraCapabilities caps_;  // what the node map has of the config's features (Connect)
  bool exposed_ = false;         // Expose() has triggered a frame that Retrieve() has not taken
  _ArvBuffer* early_ = nullptr;  // that frame, when it arrived before the exposure's end was seen
  // Buffers handed out in Frames return to this stream; it outlives them through this token.
  std::shared_ptr<_ArvStream> stream_owner_;
};

}  // namespace gonio::backends
