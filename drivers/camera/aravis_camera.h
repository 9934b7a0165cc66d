// The camera over GenICam with Aravis 0.8: opened by numeric IP (GigE Vision) or USB3 Vision id,
// never by discovery (shared/DESIGN.md network rules); TriggerMode On with TriggerSoftware, a
// pool of stream buffers, failed or incomplete buffers re-triggered a bounded number of times, and
// a reopen when the camera has dropped off the network.
#pragma once

#include <memory>

#include "drivers/camera/camera.h"

struct _ArvCamera;
struct _ArvStream;
struct _ArvBuffer;

namespace gonio::drivers {

class AravisCamera final : public Camera {
 public:
  static Result<std::unique_ptr<AravisCamera>> Open(CameraSettings settings);
  ~AravisCamera() override;

  std::string Identity() const override { return identity_; }
  Status SetExposure(double seconds) override;
  Result<double> Exposure() override;
  Result<cv::Size> ImageSize() override;
  Result<Frame> Snap() override;
  Result<double> TemperatureC() override;
  Status SetShutter(bool open) override;
  Status SetCooling(bool on, double setpoint_c) override;
  Status CoolAndWait(const TemperatureWait& w) override;

  int reopens() const { return reopens_; }

 private:
  AravisCamera() = default;
  Status Connect();  // camera, settings, stream
  void Disconnect();
  Status Reopen();  // Disconnect, Connect, restore the exposure; counts reopens_
  Status Configure();
  // This trigger's frame (any status but CLEARED) within wait_s, or null.
  _ArvBuffer* PopFrame(double wait_s);
  // One trigger and its retries; kTimeout carries only the last problem (in *last_problem).
  Result<Frame> SnapOnce(int first_attempt, std::string* last_problem);

  CameraSettings s_;
  std::string identity_;
  _ArvCamera* camera_ = nullptr;
  _ArvStream* stream_ = nullptr;
  double exposure_s_ = 0.1;
  int reopens_ = 0;
  // Buffers handed out in Frames return to this stream; it outlives them through this token.
  std::shared_ptr<_ArvStream> stream_owner_;
};

}  // namespace gonio::drivers
