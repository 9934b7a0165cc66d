// The camera over GenICam with Aravis 0.8: opened by numeric IP (GigE Vision) or USB3 Vision id,
// never by discovery (docs/design.md network rules); TriggerMode On with TriggerSoftware, a
// pool of stream buffers, failed or incomplete buffers re-triggered a bounded number of times, and
// a reopen when the camera has dropped off the network. Expose() watches SFNC's
// AcquisitionStatus (ExposureActive) when the camera has it, so readout can overlap motion. An
// exposure that begins and ends between two reads (under about a millisecond) looks the same as
// one not yet begun: Expose() then returns when its frame arrives, with nothing overlapped. An
// SFNC counter of exposure ends would remove that case; it is not used yet.
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
  int Reconnections() const override { return reopens_; }
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
  // This trigger's frame (any status but CLEARED) within wait_s, or null.
  _ArvBuffer* PopFrame(double wait_s);
  // Drains stale frames and triggers one. kBusy: every buffer is held by earlier Frames; kIo: the
  // trigger was not accepted (the camera may have gone).
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
  bool reports_end_ = false;          // the status feature exists (Connect)
  devices::CameraCapabilities caps_;  // what the node map has of the config's features (Connect)
  bool exposed_ = false;         // Expose() has triggered a frame that Retrieve() has not taken
  _ArvBuffer* early_ = nullptr;  // that frame, when it arrived before the exposure's end was seen
  // Buffers handed out in Frames return to this stream; it outlives them through this token.
  std::shared_ptr<_ArvStream> stream_owner_;
};

}  // namespace gonio::backends
