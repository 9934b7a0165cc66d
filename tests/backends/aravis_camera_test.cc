// The camera driver (backends/aravis_camera.h) against the simulated cooled CCD over real
// GigE Vision on 127.0.0.1 (the CTest resource lock "gvcp"): opening by IP, frames that view the
// stream's buffers, retries of incomplete and lost frames from the fault plan, reopening a camera
// that went away, the split frame that lets the stages move during readout, and cooling to a
// stable temperature.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>

#include <atomic>
#include <cstdio>
#include <memory>
#include <thread>

#include "backends/aravis_camera.h"
#include "sim/camera/camera.h"
#include "sim/truth/ground_truth.h"

namespace gonio {
namespace {

using backends::AravisCamera;
using devices::CameraSettings;
using sim::FaultKind;

class CameraDriver : public ::testing::Test {
 protected:
  void Start(std::vector<sim::FaultEvent> faults = {}) {
    plan = std::make_unique<sim::FaultPlan>(std::move(faults), 1);
    sim::CameraOptions o = options;
    o.sensor.sensor_width = o.sensor.sensor_height = 128;
    o.sensor.mm_per_pixel = 0.64;
    auto cam = sim::SimulatedCamera::StartGigE(
        clock, scene,
        [this] {
          return sim::StageAngles{0, arm_deg.load(), 0};
        },
        lamp, o, plan.get());
    ASSERT_TRUE(cam.ok()) << cam.error().message;
    sim_camera = std::move(*cam);
  }
  std::unique_ptr<AravisCamera> Open(CameraSettings s = {}, double frame_timeout_s = 0.5) {
    s.frame_timeout_s = frame_timeout_s;
    auto c = AravisCamera::Open(s);
    EXPECT_TRUE(c.ok()) << c.error().message;
    return c.ok() ? std::move(*c) : nullptr;
  }

  sim::ScaledClock clock{100.0};
  sim::Lamp lamp{sim::LampOptions{.drift_per_hour = 0, .wander_amplitude = 0, .flicker_rms = 0}};
  sim::Scene scene{sim::BenchGeometry{}, sim::MicrofacetTruth("beckmann", 0.344, 1.51)};
  std::unique_ptr<sim::FaultPlan> plan;
  sim::CameraOptions options;
  std::atomic<double> arm_deg{180};  // the arm the camera sits on (180: straight through)
  std::unique_ptr<sim::SimulatedCamera> sim_camera;
};

TEST_F(CameraDriver, OpensByIpAndFramesViewThePoolsBuffers) {
  Start();
  CameraSettings s;
  s.buffers = 2;
  s.retries = 0;
  auto cam = Open(s);
  ASSERT_TRUE(cam);
  EXPECT_NE(cam->Identity().find("gonio"), std::string::npos) << cam->Identity();
  ASSERT_TRUE(cam->SetExposure(0.05).ok());
  EXPECT_NEAR(*cam->Exposure(), 0.05, 1e-6);
  auto f1 = cam->Snap();
  ASSERT_TRUE(f1.ok()) << f1.error().message;
  EXPECT_EQ(f1->image.cols, 128);
  EXPECT_EQ(f1->image.rows, 128);
  EXPECT_GT(cv::mean(f1->image(cv::Rect(60, 60, 8, 8)))[0], 600);  // lit patch above bias 500
  auto f2 = cam->Snap();
  ASSERT_TRUE(f2.ok());
  // Both buffers are held by the frames (views, not copies): a third frame has nowhere to land,
  // and the caller is told so at once.
  auto f3 = cam->Snap();
  ASSERT_FALSE(f3.ok());
  EXPECT_EQ(f3.error().code, ErrorCode::kBusy);
  f1 = Error{ErrorCode::kAborted, "released"};  // gives its buffer back
  EXPECT_TRUE(cam->Snap().ok());
}

TEST_F(CameraDriver, IncompleteAndLostFramesAreRetried) {
  Start({sim::OnOpportunity(FaultKind::kFrameIncomplete, 1),
         sim::OnOpportunity(FaultKind::kFrameDrop, 3)});
  auto cam = Open();
  ASSERT_TRUE(cam);
  ASSERT_TRUE(cam->SetExposure(0.01).ok());
  auto a = cam->Snap();  // frame 1 incomplete, frame 2 fine
  ASSERT_TRUE(a.ok()) << a.error().message;
  EXPECT_EQ(a->attempts, 2);
  EXPECT_NE(a->retried_because.find("incomplete"), std::string::npos) << a->retried_because;
  auto b = cam->Snap();  // frame 3 lost, frame 4 fine
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_EQ(b->attempts, 2);
  EXPECT_EQ(b->retried_because.rfind("no frame", 0), 0u) << b->retried_because;
}

// GigE Vision's heartbeat: the driver gives the camera a timeout a loaded host can keep
// (heartbeat_timeout_s), and when the camera drops its control anyway (the fault plan's
// control_lost, here DropControl: CCP cleared, streaming stops), Aravis's control-lost signal makes
// the next trigger reopen at once, rather than after every retry has timed out silently.
TEST_F(CameraDriver, TheHeartbeatTimeoutIsSetAndALostControlIsRetakenAtTheNextTrigger) {
  Start();
  CameraSettings s;
  s.heartbeat_timeout_s = 7.5;
  auto cam = Open(s);
  ASSERT_TRUE(cam);
  EXPECT_EQ(sim_camera->HeartbeatTimeoutMs(), 7500u);
  ASSERT_TRUE(cam->SetExposure(0.01).ok());
  ASSERT_TRUE(cam->Snap().ok());
  // Once we hold it (a fault timed from the start can land while an ASan build still opens).
  sim_camera->DropControl();
  // Aravis's heartbeat thread reads the privilege about once a second.
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));
  auto f = cam->Snap();
  ASSERT_TRUE(f.ok()) << f.error().message;
  // The first attempt, reopened and triggered again: silent retries would have needed all of
  // them (the default 2 retries, 3 attempts) before the reopen, and said "no frame".
  EXPECT_EQ(f->attempts, 1) << f->retried_because;
  EXPECT_NE(f->retried_because.find("control lost"), std::string::npos) << f->retried_because;
  EXPECT_EQ(cam->reopens(), 1);
  // What a run's log says of the reconnection (the engine names it when it costs a point).
  EXPECT_EQ(cam->LastReconnectionCause().empty(), false);
  EXPECT_NE(cam->LastReconnectionCause().find("control lost"), std::string::npos)
      << cam->LastReconnectionCause();
}

TEST_F(CameraDriver, FramesThatNeverComeGiveATimeoutAfterTheRetries) {
  Start({sim::WithProbability(FaultKind::kFrameDrop, 1.0, 100)});
  CameraSettings s;
  s.retries = 1;
  auto cam = Open(s);
  ASSERT_TRUE(cam);
  auto r = cam->Snap();
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kTimeout);
  EXPECT_NE(r.error().message.find("after 1 retries"), std::string::npos) << r.error().message;
  // The reopen says what the stream saw: a camera that sent nothing, not frames thrown away.
  EXPECT_NE(cam->LastReconnectionCause().find("completed 0 frames, received 0 packets"),
            std::string::npos)
      << cam->LastReconnectionCause();
}

TEST_F(CameraDriver, ACameraThatWentAwayIsReopened) {
  Start();
  auto cam = Open();
  ASSERT_TRUE(cam);
  ASSERT_TRUE(cam->Snap().ok());
  sim_camera.reset();  // power cycle: the camera leaves and comes back
  Start();
  auto f = cam->Snap();
  ASSERT_TRUE(f.ok()) << f.error().message;
  EXPECT_EQ(cam->reopens(), 1);
}

// The link check (the daemon's watch beside an exposure): a GVCP register read on a socket of its
// own, answered while the camera is there, an error within a second once it has gone (nothing
// listens on its GVCP port: ICMP port unreachable), and answered again once it is back, with no
// reopen of the driver's own connection.
TEST_F(CameraDriver, TheLinkCheckSeesACameraGoneWithinASecondAndBackAgain) {
  Start();
  auto cam = Open();
  ASSERT_TRUE(cam);
  EXPECT_TRUE(cam->CheckLink().ok());
  sim_camera.reset();
  const auto t0 = std::chrono::steady_clock::now();
  const Status gone = cam->CheckLink();
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_FALSE(gone.ok());
  EXPECT_NE(gone.error().message.find("camera 127.0.0.1"), std::string::npos)
      << gone.error().message;
  std::printf("a gone camera's link check failed after %.3f s: %s\n", took,
              gone.error().message.c_str());
  EXPECT_LT(took, 1.0);  // two waits of 250 ms at most, whatever the host
  Start();
  EXPECT_TRUE(cam->CheckLink().ok());
  EXPECT_EQ(cam->reopens(), 0);
}

// Issue #18: a camera that stays away long enough for the reopen to fail, then comes back, is
// used again: the failed reopen left no camera, which the next calls opened again (they read it
// as a pool whose buffers were all held: "all 4 frame buffers are held by earlier Frames").
TEST_F(CameraDriver, ACameraThatStaysAwayThroughAFailedReopenIsUsedOnceItIsBack) {
  Start();
  CameraSettings s;
  s.retries = 1;
  auto cam = Open(s);
  ASSERT_TRUE(cam);
  ASSERT_TRUE(cam->SetExposure(0.05).ok());
  ASSERT_TRUE(cam->Snap().ok());
  sim_camera.reset();  // gone, and not back for the reopen
  auto lost = cam->Snap();
  ASSERT_FALSE(lost.ok());
  EXPECT_EQ(lost.error().code, ErrorCode::kNotConnected) << lost.error().message;
  Start();  // back
  auto f = cam->Snap();
  ASSERT_TRUE(f.ok()) << f.error().message;
  EXPECT_NEAR(f->exposure_s, 0.05, 1e-5);  // the exposure survived the failed reopen
  EXPECT_TRUE(cam->TemperatureC().ok());
  EXPECT_TRUE(cam->Expose().ok());
  EXPECT_TRUE(cam->Retrieve().ok());
}

// The split frame (Camera::Expose / Retrieve): Expose() returns when the sensor stops
// integrating, so an arm moved right after it leaves the frame as it was; the camera is read out
// slowly here (8.2 s) so that a frame taking its angles at the readout's end would show the move.
// The exposure (2 s, 20 ms of real time at x100) is long enough for the driver to see it active:
// one that begins and ends between two status reads is only seen when its frame arrives.
TEST_F(CameraDriver, ExposeReturnsAtTheExposuresEndSoAMoveDuringReadoutLeavesTheFrame) {
  options.sensor_options.readout_pixel_rate_hz = 2e3;
  Start();
  auto cam = Open();
  ASSERT_TRUE(cam);
  ASSERT_TRUE(cam->ReportsExposureEnd());
  ASSERT_TRUE(cam->SetExposure(2.0).ok());
  const cv::Rect patch(60, 60, 8, 8);
  auto level = [&](const devices::Frame& f) { return cv::mean(f.image(patch))[0] - 500; };
  auto straight = cam->Snap();
  ASSERT_TRUE(straight.ok()) << straight.error().message;
  arm_deg = 150;
  auto off = cam->Snap();
  ASSERT_TRUE(off.ok()) << off.error().message;
  const double lit = level(*straight), dim = level(*off);
  ASSERT_GT(lit, 2 * dim) << "the patch must tell the two arm angles apart";
  straight = off = Error{ErrorCode::kAborted, "released"};

  arm_deg = 180;
  const double t0 = clock.Now();
  ASSERT_TRUE(cam->Expose().ok());
  const double exposed_at = clock.Now() - t0;
  arm_deg = 150;  // the readout has begun: the stages may go
  auto f = cam->Retrieve();
  ASSERT_TRUE(f.ok()) << f.error().message;
  const double retrieved_at = clock.Now() - t0;
  // Returned after the exposure (2 s) and well before the readout's end (8.2 s later).
  EXPECT_GE(exposed_at, 2.0);
  EXPECT_LT(exposed_at, 2.0 + 4.1);
  EXPECT_GT(retrieved_at, 2.0 + 8.2);
  EXPECT_NEAR(level(*f), lit, 0.1 * lit) << "dim " << dim;
}

TEST_F(CameraDriver, ARetrievalLostAfterExposeIsAnErrorAndNotRetried) {
  Start();
  CameraSettings s;
  s.retries = 3;
  // The firmware renders a frame in the thread that ends exposures: on a loaded CI machine the
  // 0.5 s the other tests allow has been too short for this exposure's end to be seen.
  auto cam = Open(s, 2.0);
  ASSERT_TRUE(cam);
  auto r = cam->Retrieve();
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kFailedPrecondition);
  // Long enough (50 ms of real time at x100) for Expose to see the sensor integrate: a 1 ms
  // exposure can begin and end between two status reads, and then only its frame would show
  // that it ended, which this test drops (it failed so under ASan in CI).
  ASSERT_TRUE(cam->SetExposure(5.0).ok());
  sim_camera->DropFrames(1);
  const Status exposed = cam->Expose();
  ASSERT_TRUE(exposed.ok()) << exposed.error().message;
  r = cam->Retrieve();
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kTimeout) << r.error().message;
  auto again = cam->Snap();  // the caller's retake
  ASSERT_TRUE(again.ok()) << again.error().message;
  // Within the driver's own budget: its retries and one reopen. One clean-clone CI run (loaded
  // by fuzz replays) needed all of it here, 4 silent attempts then a reopen: the camera had
  // dropped control on a missed 3 s heartbeat (see TheHeartbeatTimeoutIsSet..., which gives the
  // same 4 attempts without the driver's control-lost handling).
  EXPECT_LE(again->attempts, s.retries + 2) << again->retried_because;
  // A camera without the status feature cannot split a frame: Expose says so.
  CameraSettings none;
  none.features.status = "NoSuchFeature";
  cam.reset();
  auto plain = Open(none);
  ASSERT_TRUE(plain);
  EXPECT_FALSE(plain->ReportsExposureEnd());
  const Status e = plain->Expose();
  ASSERT_FALSE(e.ok());
  EXPECT_EQ(e.error().code, ErrorCode::kFailedPrecondition);
  EXPECT_TRUE(plain->Snap().ok());
}

// Issue #18: a daemon stopping does not wait for the exposure in hand. Interrupted, Snap and
// Expose return kAborted long before the exposure would have ended (300 simulated seconds, 3 s
// here), and once the flag clears the camera takes frames again.
TEST_F(CameraDriver, AnInterruptEndsTheExposureInHandAndTheCameraIsReadyAgain) {
  Start();
  auto cam = Open();
  ASSERT_TRUE(cam);
  std::atomic<bool> interrupt{false};
  cam->SetInterrupt(&interrupt);
  ASSERT_TRUE(cam->SetExposure(300.0).ok());
  for (const bool split : {false, true}) {
    interrupt = false;
    std::thread stopper([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
      interrupt = true;
    });
    const double t0 = clock.Now();
    Status s = OkStatus();
    if (split) {
      s = cam->Expose();
    } else {
      auto f = cam->Snap();
      if (!f.ok()) s = f.error();
    }
    const double took = clock.Now() - t0;
    stopper.join();
    ASSERT_FALSE(s.ok()) << (split ? "Expose" : "Snap") << " ran to the exposure's end";
    EXPECT_EQ(s.error().code, ErrorCode::kAborted) << s.error().message;
    EXPECT_LT(took, 150.0) << "simulated seconds; the exposure was 300";
  }
  interrupt = false;
  ASSERT_TRUE(cam->SetExposure(0.05).ok());
  auto f = cam->Snap();
  ASSERT_TRUE(f.ok()) << f.error().message;
  // Ready again: the camera takes frames. Not necessarily on the first trigger: beside the fuzz
  // replays in CI, the first triggers after an interrupt have gone unanswered for 3 attempts of
  // 0.55 s until the driver reopened the camera (and, at stop 25, frames arrived short of
  // packets). Which side leaves the trigger unanswered under load, the simulator's firmware loop
  // or the driver's pairing of triggers and frames, is open (backends/README.md, "Frames and
  // triggers under load"); the retry's cause is printed so that a CI log says which it was.
  if (f->attempts > 1)
    std::printf("the first frame after the interrupt took %d attempts: %s\n", f->attempts,
                f->retried_because.c_str());
  cam->SetInterrupt(nullptr);
}

// Frames are paired with triggers by the camera's clock (GigE Vision timestamp latch): a frame
// exposed before the latch the driver takes ahead of its trigger belongs to an earlier trigger,
// however late it arrives. Here a stray trigger starts an exposure with the arm straight through;
// the arm moves mid-exposure and the driver triggers while that frame is still in the camera.
// Paired by order alone, the stray frame (half lit, half dim) would be taken for this trigger's,
// as a late frame was on a loaded CI machine (stop 26's note: values 35 % off with a σ that did
// not cover it).
TEST_F(CameraDriver, AFrameExposedBeforeItsTriggerIsRefusedHoweverLateItArrives) {
  Start();
  auto cam = Open(CameraSettings{}, 2.0);
  ASSERT_TRUE(cam);
  ASSERT_TRUE(cam->ChecksFrameStamps()) << "the simulated camera latches its timestamp";
  ASSERT_TRUE(cam->SetExposure(4.0).ok());  // 40 ms of real time at x100
  const cv::Rect patch(60, 60, 8, 8);
  auto level = [&](const devices::Frame& f) { return cv::mean(f.image(patch))[0] - 500; };
  double lit = 0, dim = 0;
  {
    auto f = cam->Snap();
    ASSERT_TRUE(f.ok()) << f.error().message;
    lit = level(*f);
    arm_deg = 150;
    f = cam->Snap();
    ASSERT_TRUE(f.ok()) << f.error().message;
    dim = level(*f);
  }
  ASSERT_GT(lit, 3 * dim) << "the patch must tell the two arm angles apart";
  for (int round = 0; round < 3; ++round) {
    arm_deg = 180;
    sim_camera->StrayTrigger();
    const auto t0 = std::chrono::steady_clock::now();
    while (!sim_camera->Exposing() &&
           std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5))
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    ASSERT_TRUE(sim_camera->Exposing()) << "the stray trigger was not taken";
    arm_deg = 150;
    const int stale_before = cam->StaleFrames();
    auto f = cam->Snap();
    ASSERT_TRUE(f.ok()) << f.error().message;
    EXPECT_NEAR(level(*f), dim, 0.1 * lit) << "round " << round << ": lit " << lit;
    EXPECT_EQ(cam->StaleFrames(), stale_before + 1) << "round " << round;
  }
  // The split frame: Expose watches ExposureActive, which the stray exposure raises and lowers
  // too, so the end it reports may be that one's. The frame is then refused, to be retaken: the
  // stages may have moved during it.
  ASSERT_TRUE(cam->ReportsExposureEnd());
  arm_deg = 180;
  sim_camera->StrayTrigger();
  const auto t0 = std::chrono::steady_clock::now();
  while (!sim_camera->Exposing() && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5))
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_TRUE(sim_camera->Exposing()) << "the stray trigger was not taken";
  arm_deg = 150;
  ASSERT_TRUE(cam->Expose().ok());
  auto split = cam->Retrieve();
  ASSERT_FALSE(split.ok()) << "a frame whose exposure end may have been another's was kept";
  EXPECT_EQ(split.error().code, ErrorCode::kDeviceFault) << split.error().message;
  EXPECT_NE(split.error().message.find("earlier trigger"), std::string::npos)
      << split.error().message;
  auto retake = cam->Snap();
  ASSERT_TRUE(retake.ok()) << retake.error().message;
  EXPECT_NEAR(level(*retake), dim, 0.1 * lit);
}

// A camera's firmware may take a latch late (busy elsewhere; the simulator's, rendering a frame
// between steps under ASan on a loaded host, took over a second): the driver waits
// latch_timeout_s for it, whatever the frame timeout. A latch never seen at a trigger is a camera
// that no longer answers, and it is reopened; one that latched before and does not at the reopen
// is not then paired by order (it was, at stop 39's CI: a late frame took the next trigger's
// place and values came out 200 sigma off). It stays closed, the error says why, and the next
// Snap opens it with its latch.
TEST_F(CameraDriver, ASlowLatchIsWaitedForAndOneNeverSeenIsNotPairedByOrder) {
  auto slow = [](std::int64_t n, double s) {
    sim::FaultEvent e = sim::OnOpportunity(FaultKind::kLatchSlow, n);
    e.duration_s = s;
    return e;
  };
  // Latches: 1 at open; 2 the first trigger's, 0.4 s of real time at x100; 3 the next trigger's,
  // 5 s (the reopen's probe, written while it is pending, waits for the same one). The second
  // event's opportunities are 1 and 3: an event does not see the call an earlier one fired in.
  Start({slow(2, 40), slow(2, 500)});
  CameraSettings s;
  s.latch_timeout_s = 1.0;
  auto cam = Open(s, 0.25);  // a frame timeout shorter than the slow latch
  ASSERT_TRUE(cam);
  ASSERT_TRUE(cam->ChecksFrameStamps());
  ASSERT_TRUE(cam->SetExposure(0.05).ok());
  auto f = cam->Snap();
  ASSERT_TRUE(f.ok()) << f.error().message;
  EXPECT_EQ(cam->Reconnections(), 0) << "a latch within latch_timeout_s is waited for";
  const auto t0 = std::chrono::steady_clock::now();
  f = cam->Snap();
  ASSERT_FALSE(f.ok()) << "reopened without its latch, the camera was used paired by order";
  EXPECT_NE(f.error().message.find("timestamp latch"), std::string::npos) << f.error().message;
  EXPECT_FALSE(cam->ChecksFrameStamps());
  // Once the camera has taken the pending latch, it answers again.
  std::this_thread::sleep_until(t0 + std::chrono::milliseconds(5500));
  f = cam->Snap();
  ASSERT_TRUE(f.ok()) << f.error().message;
  EXPECT_TRUE(cam->ChecksFrameStamps());
  EXPECT_GE(cam->Reconnections(), 1);
}

TEST_F(CameraDriver, CoolsToASetpointAndHoldsIt) {
  Start();
  auto cam = Open();
  ASSERT_TRUE(cam);
  // From ambient 20 C to 10 C with tau = 60 s: within 0.5 C after 3 tau = 180 s (1.8 s at x100).
  devices::TemperatureWait w{.setpoint_c = 10,
                             .tolerance_c = 0.5,
                             .hold_s = 0.3,
                             .timeout_s = 10,
                             .ramp_c_per_min = 0,
                             .poll_s = 0.05};
  const Status s = cam->CoolAndWait(w);
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_NEAR(*cam->TemperatureC(), 10, 0.5);
}

TEST_F(CameraDriver, AFailedCoolerIsATimeoutThatSaysWhereTheSensorIs) {
  Start({sim::AtTime(FaultKind::kCoolerFail, 0)});
  auto cam = Open();
  ASSERT_TRUE(cam);
  devices::TemperatureWait w{.setpoint_c = -10,
                             .tolerance_c = 0.5,
                             .hold_s = 0.3,
                             .timeout_s = 0.5,
                             .ramp_c_per_min = 0,
                             .poll_s = 0.05};
  const Status s = cam->CoolAndWait(w);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kTimeout);
  EXPECT_NE(s.error().message.find("sensor at 20"), std::string::npos) << s.error().message;
}

TEST(CameraDriverOpen, RefusesNamesThatWouldNeedDiscovery) {
  CameraSettings s;
  s.address = "my-camera.local";
  auto c = AravisCamera::Open(s);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, ErrorCode::kInvalidArgument);
  s.address = "127.0.0.1";
  s.pixel_format = "RGB8";
  EXPECT_FALSE(AravisCamera::Open(s).ok());
}

}  // namespace
}  // namespace gonio
