// The stage driver (backends/modbus_stage.h) against the simulated controller over real
// Modbus TCP and RTU: concurrent moves, travel limits, backlash compensation, and the fault plan's
// bus faults (retried, reconnected) and device faults (errors at once, other axes stopped).
#include <gtest/gtest.h>

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
      link.kind = "rtu";
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
  std::unique_ptr<ModbusStageController> Open(double overshoot = 0) {
    auto c = ModbusStageController::Open(link, Settings(overshoot));
    EXPECT_TRUE(c.ok()) << c.error().message;
    return c.ok() ? std::move(*c) : nullptr;
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

TEST(StageDriverOpen, AnAbsentControllerIsNamedInTheError) {
  ModbusLink link;
  link.port = 1;  // nothing listens there
  auto c = ModbusStageController::Open(link, {AxisSettings{.name = "sample"}});
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, ErrorCode::kNotConnected);
  EXPECT_NE(c.error().message.find("127.0.0.1:1"), std::string::npos) << c.error().message;
}

}  // namespace
}  // namespace gonio
