// The stage driver (backends/modbus_stage.h) against the simulated controller over real
// Modbus TCP and RTU: concurrent moves, travel limits, backlash compensation, and the fault plan's
// bus faults (retried, reconnected) and device faults (errors at once, other axes stopped).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <string>
#include <thread>

#include "backends/modbus_stage.h"
#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/stage/axis.h"
#include "sim/stage/modbus_rtu_server.h"
#include "sim/stage/modbus_tcp_server.h"

namespace gonio {
namespace {

using backends::ModbusStageController;
using devices::AxisSettings;
using devices::ModbusLink;
using sim::FaultEvent;
using sim::FaultKind;
using sim::FaultPlan;

// Two simulated axes (sample, arm) at x50 speed; the driver's settings mirror their gearing.
class StageDriver : public ::testing::Test {
 protected:
  void Serve(sim::AxisOptions sample_opts = {}, std::vector<FaultEvent> faults = {},
             bool rtu = false) {
    plan = std::make_unique<FaultPlan>(std::move(faults), 3);
    sample = std::make_unique<sim::SimulatedAxis>(clock, sample_opts, "sample", plan.get());
    arm = std::make_unique<sim::SimulatedAxis>(clock, sim::AxisOptions{}, "arm", plan.get());
    link.response_timeout_s = 0.2;
    if (rtu) {
      auto s = sim::StageModbusRtuServer::Start({sample.get(), arm.get()}, {}, plan.get(), &clock);
      ASSERT_TRUE(s.ok()) << s.error().message;
      rtu_server = std::move(*s);
      link.kind = devices::ModbusTransport::kRtu;
      link.device = rtu_server->pty_path();
    } else {
      auto s = sim::StageModbusTcpServer::Start({sample.get(), arm.get()}, 0, plan.get(), &clock);
      ASSERT_TRUE(s.ok()) << s.error().message;
      tcp_server = std::move(*s);
      link.port = tcp_server->port();
    }
  }
  std::vector<AxisSettings> Settings(double overshoot = 0) {
    AxisSettings s{.name = "sample", .slave_id = 1};
    s.min_deg = -90, s.max_deg = 90;
    s.speed_deg_s = 20, s.acceleration_deg_s2 = 100;
    s.backlash_overshoot_deg = overshoot;
    AxisSettings a = s;
    a.name = "arm", a.slave_id = 2, a.degrees_at_zero = 180, a.min_deg = 0, a.max_deg = 360;
    a.backlash_overshoot_deg = 0;
    return {s, a};
  }
  std::unique_ptr<ModbusStageController> Open(double overshoot = 0,
                                              devices::StageRegisterProfile profile = {}) {
    auto c = ModbusStageController::Open(link, Settings(overshoot), profile);
    EXPECT_TRUE(c.ok()) << c.error().message;
    return c.ok() ? std::move(*c) : nullptr;
  }
  // Another client starts a move of the sample axis to `steps` (direct data operation, written
  // at the register level from docs/stage_register_map.md: type 1, speed 20000, trigger 1).
  void MoveElsewhere(std::int32_t steps) {
    const std::uint32_t v[8] = {0,    1, static_cast<std::uint32_t>(steps), 20000, 100000, 100000,
                                1000, 1};
    std::uint16_t w[16];
    for (int k = 0; k < 8; ++k)
      w[2 * k] = static_cast<std::uint16_t>(v[k] >> 16),
            w[2 * k + 1] = static_cast<std::uint16_t>(v[k] & 0xFFFF);
    sample->Write(0x0058, w, 16);
  }

  sim::ScaledClock clock{50.0};
  std::unique_ptr<FaultPlan> plan;
  std::unique_ptr<sim::SimulatedAxis> sample, arm;
  std::unique_ptr<sim::StageModbusTcpServer> tcp_server;
  std::unique_ptr<sim::StageModbusRtuServer> rtu_server;
  ModbusLink link;
};

TEST_F(StageDriver, AxesMoveTogetherAndReadBackTheirTargets) {
  Serve();
  auto c = Open();
  ASSERT_TRUE(c);
  const double t0 = clock.Now();
  ASSERT_TRUE(c->MoveTo({{"sample", 40}, {"arm", 120}}).ok());
  const double took = clock.Now() - t0;
  // Each move alone: 0.2 s up, the cruise, 0.2 s down: 40 deg -> 2.2 s, 60 deg -> 3.2 s. Together
  // they take the longer one, not the sum (5.4 s); settling and polling add a little.
  EXPECT_GT(took, 3.2);
  EXPECT_LT(took, 4.5);
  EXPECT_NEAR(c->ReadStatus("sample")->position_deg, 40, 1e-3);
  EXPECT_NEAR(c->ReadStatus("arm")->position_deg, 120, 1e-3);
  EXPECT_NEAR(arm->MotorSteps(), (120 - 180) * 1000.0, 0.5);  // the gearing's offset applied
}

TEST_F(StageDriver, TargetsOutsideTheTravelLimitsAreRefusedBeforeAnythingMoves) {
  Serve();
  auto c = Open();
  ASSERT_TRUE(c);
  const Status s = c->MoveTo({{"arm", 100}, {"sample", 95}});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kInvalidArgument);
  EXPECT_NE(s.error().message.find("travel limits"), std::string::npos) << s.error().message;
  EXPECT_EQ(arm->MotorSteps(), 0);  // the valid axis did not move either
  EXPECT_FALSE(c->MoveTo({{"elbow", 1}}).ok());
}

TEST_F(StageDriver, OneSidedApproachMakesBacklashRepeatable) {
  sim::AxisOptions o;
  o.backlash_steps = 40;  // 0.04 deg of lost motion
  Serve(o);
  auto plain = Open(0);
  ASSERT_TRUE(plain);
  ASSERT_TRUE(plain->MoveTo({{"sample", 10}}).ok());
  const double from_below = sample->PositionSteps();
  ASSERT_TRUE(plain->MoveTo({{"sample", 20}}).ok());
  ASSERT_TRUE(plain->MoveTo({{"sample", 10}}).ok());
  EXPECT_NEAR(sample->PositionSteps() - from_below, 40, 1e-6);  // the hysteresis, uncompensated
  plain.reset();
  auto comp = Open(0.1);  // overshoot 0.1 deg > backlash
  ASSERT_TRUE(comp);
  ASSERT_TRUE(comp->MoveTo({{"sample", 20}}).ok());
  ASSERT_TRUE(comp->MoveTo({{"sample", 10}}).ok());  // from above: down to 9.9, then up
  EXPECT_NEAR(sample->PositionSteps(), from_below, 1e-6);
  EXPECT_NEAR(comp->ReadStatus("sample")->position_deg, 10, 1e-3);
}

// Issue #18/#19: a target at (or within the overshoot of) the lower travel limit is reached,
// not refused as "no room below it" (a plan with a view there was retried for ever).
TEST_F(StageDriver, TargetsAtTheLowerLimitAreReached) {
  sim::AxisOptions o;
  o.backlash_steps = 40;
  Serve(o);
  auto c = Open(0.1);
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->MoveTo({{"sample", -80}}).ok());
  for (double target : {-90.0, -89.95, -90.0}) {
    const Status s = c->MoveTo({{"sample", target}});
    ASSERT_TRUE(s.ok()) << target << ": " << s.error().message;
    EXPECT_NEAR(c->ReadStatus("sample")->position_deg, target, 1e-3) << target;
  }
  // Beyond the limit is still refused before anything moves.
  EXPECT_FALSE(c->MoveTo({{"sample", -90.01}}).ok());
}

TEST_F(StageDriver, TransientTimeoutsAreRetriedAndTheMoveCompletes) {
  Serve({}, {sim::WithProbability(FaultKind::kModbusTimeout, 0.15, 6)});
  auto c = Open();
  ASSERT_TRUE(c);
  const Status s = c->MoveTo({{"sample", 5}, {"arm", 185}});
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_GT(c->retried(), 0);
  EXPECT_EQ(static_cast<int>(plan->Fired().size()), c->retried());
}

TEST_F(StageDriver, DroppedConnectionIsReconnected) {
  Serve({}, {sim::OnOpportunity(FaultKind::kModbusDrop, 6)});
  auto c = Open();
  ASSERT_TRUE(c);
  const Status s = c->MoveTo({{"sample", 3}});
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(c->reconnects(), 1);
}

TEST_F(StageDriver, CrcErrorsOnRtuAreRetried) {
  Serve({}, {sim::WithProbability(FaultKind::kModbusCrc, 0.2, 5)}, /*rtu=*/true);
  auto c = Open();
  ASSERT_TRUE(c);
  const Status s = c->MoveTo({{"sample", -4}, {"arm", 170}});
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_GT(c->retried(), 0);
  EXPECT_NEAR(c->ReadStatus("arm")->position_deg, 170, 1e-3);
}

TEST_F(StageDriver, ABusThatNeverAnswersGivesATimeoutNotAHang) {
  Serve();
  auto c = Open();
  ASSERT_TRUE(c);
  tcp_server.reset();  // the controller goes away; reconnects are refused
  const Status s = c->MoveTo({{"sample", 1}});
  ASSERT_FALSE(s.ok());
  EXPECT_TRUE(s.error().code == ErrorCode::kNotConnected || s.error().code == ErrorCode::kTimeout)
      << s.error().ToString();
  EXPECT_NE(s.error().message.find("after 3 retries"), std::string::npos) << s.error().message;
}

TEST_F(StageDriver, StallIsADeviceFaultAndTheOtherAxisStops) {
  Serve({}, {sim::OnOpportunity(FaultKind::kAxisStall, 1, "sample")});
  auto c = Open();
  ASSERT_TRUE(c);
  const Status s = c->MoveTo({{"sample", 30}, {"arm", 300}});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kDeviceFault);
  EXPECT_NE(s.error().message.find("0x10"), std::string::npos) << s.error().message;
  EXPECT_EQ(c->retried(), 0);  // an alarm is not retried
  // The arm was stopped short of 300 deg (its move takes 6.2 s; the stall came at 0.85 s).
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_LT(c->ReadStatus("arm")->position_deg, 250);
  EXPECT_FALSE(arm->Moving());
  ASSERT_TRUE(c->ResetAlarm("sample").ok());
  EXPECT_EQ(c->ReadStatus("sample")->alarm, 0u);
  EXPECT_TRUE(c->MoveTo({{"sample", 30}}).ok());
}

TEST_F(StageDriver, LimitSwitchIsADeviceFault) {
  sim::AxisOptions o;
  o.limit_switches = true;
  o.limit_max_steps = 50'000;  // a switch at 50 deg, inside the driver's +-90 deg limits
  Serve(o);
  auto c = Open();
  ASSERT_TRUE(c);
  const Status s = c->MoveTo({{"sample", 60}});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kDeviceFault);
  EXPECT_NE(s.error().message.find("limit switch"), std::string::npos) << s.error().message;
}

TEST_F(StageDriver, HomingReturnsEveryAxisToZero) {
  Serve();
  auto c = Open();
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->MoveTo({{"sample", 2}, {"arm", 182}}).ok());
  ASSERT_TRUE(c->Home().ok());
  EXPECT_TRUE(c->ReadStatus("sample")->homed);
  EXPECT_NEAR(c->ReadStatus("arm")->position_deg, 180, 1e-9);
}

// Issue #19: what a real AZ controller does and a forgiving simulator would not. The simulated
// sample axis latches its inputs (commands act on an off-to-on edge and stay as written), keeps
// READY off for a while after each motion and reset, or stalls without an alarm.
sim::AxisOptions RealController() {
  sim::AxisOptions o;
  o.latched_inputs = true;
  o.ready_delay_s = 0.5;  // simulated: 10 ms real at x50
  return o;
}

TEST_F(StageDriver, AStopFollowedByAMoveWorksWhenInputsAreLatched) {
  Serve(RealController());
  auto c = Open();
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->StopAll().ok());
  ASSERT_TRUE(c->MoveTo({{"sample", 20}}).ok());
  EXPECT_NEAR(sample->MotorSteps(), 20'000, 0.5);
  EXPECT_EQ(sample->IgnoredOperations(), 0);
  ASSERT_TRUE(c->StopAll().ok());
  ASSERT_TRUE(c->MoveTo({{"sample", -5}, {"arm", 190}}).ok());
  EXPECT_NEAR(sample->MotorSteps(), -5'000, 0.5);

  // A driver that writes STOP and leaves it on: the held STOP blocks the next move, and the
  // driver says so instead of waiting out the move's timeout.
  devices::StageRegisterProfile pulsed;
  pulsed.inputs_latched = false;
  pulsed.ready_timeout_s = 0.2;
  auto naive = Open(0, pulsed);
  ASSERT_TRUE(naive);
  ASSERT_TRUE(naive->StopAll().ok());
  const Status s = naive->MoveTo({{"sample", 10}});
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("not READY"), std::string::npos) << s.error().message;
  EXPECT_NE(s.error().message.find("STOP is held on"), std::string::npos) << s.error().message;
}

TEST_F(StageDriver, HomingTwiceWorksWhenInputsAreLatched) {
  Serve(RealController());
  auto c = Open();
  ASSERT_TRUE(c);
  for (const double deg : {3.0, -2.0}) {
    ASSERT_TRUE(c->MoveTo({{"sample", deg}}).ok());
    const Status homed = c->Home({"sample"});
    ASSERT_TRUE(homed.ok()) << homed.error().message;
    EXPECT_NEAR(sample->MotorSteps(), 0, 0.5) << "homing from " << deg << " deg";
    EXPECT_TRUE(c->ReadStatus("sample")->homed);
  }
  EXPECT_EQ(sample->IgnoredOperations(), 0);
}

TEST_F(StageDriver, AMoveDuringAnotherClientsMoveWaitsForReady) {
  Serve(RealController());
  auto c = Open();
  ASSERT_TRUE(c);
  std::this_thread::sleep_for(std::chrono::milliseconds(30));  // READY after power-up
  MoveElsewhere(30'000);                                       // 1.5 s simulated: 30 ms real
  ASSERT_TRUE(sample->Moving());
  const Status s = c->MoveTo({{"sample", 10}});
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_NEAR(sample->MotorSteps(), 10'000, 0.5);
  EXPECT_EQ(sample->IgnoredOperations(), 0) << "a move was written while not READY";

  // One that would not be READY in time is not written, and the error names the status bits.
  devices::StageRegisterProfile impatient;
  impatient.ready_timeout_s = 0.01;
  auto hasty = Open(0, impatient);
  ASSERT_TRUE(hasty);
  std::this_thread::sleep_for(std::chrono::milliseconds(30));  // READY again
  MoveElsewhere(-80'000);                                      // 4.5 s simulated
  ASSERT_TRUE(sample->Moving());
  const Status refused = hasty->MoveTo({{"sample", 40}});
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, ErrorCode::kDeviceFault);
  EXPECT_NE(refused.error().message.find("not READY"), std::string::npos)
      << refused.error().message;
  EXPECT_NE(refused.error().message.find("MOVE"), std::string::npos) << refused.error().message;
  EXPECT_EQ(sample->IgnoredOperations(), 0);
}

TEST_F(StageDriver, AStallWithoutAnAlarmIsReportedAsAStall) {
  sim::AxisOptions o = RealController();
  o.stall_alarm = false;  // a deviation under the controller's alarm threshold
  FaultEvent stalls = sim::OnOpportunity(FaultKind::kAxisStall, 1, "sample");
  stalls.count = 2;  // the first two moves
  Serve(o, {stalls});
  auto c = Open();
  ASSERT_TRUE(c);
  const Status s = c->MoveTo({{"sample", 30}});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kDeviceFault);
  EXPECT_NE(s.error().message.find("stalled"), std::string::npos) << s.error().message;
  EXPECT_NEAR(c->ReadStatus("sample")->position_deg, 15, 0.01);  // where it stalled

  // Verified on the commanded position, the same stall passes for a move that arrived.
  devices::StageRegisterProfile commanded;
  commanded.feedback_position = commanded.command_position;
  auto blind = Open(0, commanded);
  ASSERT_TRUE(blind);
  EXPECT_TRUE(blind->MoveTo({{"sample", -30}}).ok());
  EXPECT_GT(sample->MotorSteps(), -20'000) << "the second stall did not happen";
}

TEST_F(StageDriver, ALinkLostForGoodMidMoveSaysTheAxesMayStillMove) {
  Serve(RealController());
  link.retries = 1;
  auto c = Open();
  ASSERT_TRUE(c);
  std::thread cut([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(40));
    tcp_server.reset();  // the gateway goes away while the arm moves (6 s simulated: 120 ms)
  });
  const Status s = c->MoveTo({{"arm", 300}});
  cut.join();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("may still be moving"), std::string::npos) << s.error().message;
  EXPECT_NE(s.error().message.find("'arm' at"), std::string::npos) << s.error().message;
  EXPECT_NE(s.error().message.find("and moving"), std::string::npos) << s.error().message;
}

TEST(StageDriverOpen, AnAbsentControllerIsNamedInTheError) {
  ModbusLink link;
  link.port = 1;  // nothing listens there
  auto c = ModbusStageController::Open(link, {AxisSettings{.name = "sample"}});
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, ErrorCode::kNotConnected);
  EXPECT_NE(c.error().message.find("127.0.0.1:1"), std::string::npos) << c.error().message;
}

// The daemon's link watch calls CheckLink beside the engine's requests. A request retrying after
// the connection was lost holds the bus through its retries and reconnects (here 3 of them, with
// their back-off: a third of a second; over a second with the default timeouts): the check must
// answer from that retry rather than queue behind it (CI once saw a stage server gone reported
// after 2.3 s, by the engine's own failure, and not by the watch), and answer normally again once
// the controller is back and idle.
TEST_F(StageDriver, TheLinkCheckAnswersFromARetryInsteadOfWaitingBehindIt) {
  Serve();
  link.retries = 3;
  auto c = Open();
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->CheckLink().ok());
  const int port = tcp_server->port();
  tcp_server.reset();  // the controller goes away: connections are refused
  std::atomic<bool> engine_done{false};
  std::thread engine([&] {
    (void)c->ReadStatus("arm");  // the engine's request, retrying
    engine_done = true;
  });
  // Until that request is retrying (its first attempt has failed).
  for (int i = 0; i < 400 && c->retried() == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_GT(c->retried(), 0) << "the request did not retry";
  const Status check = c->CheckLink();
  const bool answered_first = !engine_done;
  engine.join();
  ASSERT_FALSE(check.ok());
  EXPECT_TRUE(answered_first) << "the check waited for the retrying request: "
                              << check.error().message;
  EXPECT_NE(check.error().message.find("a request is being retried"), std::string::npos)
      << check.error().message;
  EXPECT_NE(check.error().message.find("axis 'arm'"), std::string::npos) << check.error().message;
  // Back on its port, and no request retrying: the check reads the status again.
  auto s = sim::StageModbusTcpServer::Start({sample.get(), arm.get()}, port, plan.get(), &clock);
  ASSERT_TRUE(s.ok()) << s.error().message;
  tcp_server = std::move(*s);
  Status again = c->CheckLink();
  for (int i = 0; i < 20 && !again.ok(); ++i) {  // its own reconnect may take a try or two
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    again = c->CheckLink();
  }
  EXPECT_TRUE(again.ok()) << again.error().message;
}

}  // namespace
}  // namespace gonio
