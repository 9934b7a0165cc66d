// The simulated stage driver at the register level (issue #4): motion takes the time the
// trapezoidal profile says, and the documented registers behave as docs/stage_register_map.md
// describes (status bits, alarms, homing, stop). The Modbus TCP/RTU servers around it are #4's.
#include <gtest/gtest.h>

#include <cmath>

#include "sim/clock.h"
#include "sim/stage/axis.h"
#include "sim/stage/motion.h"

namespace gonio::sim {
namespace {

using namespace stage_reg;

TEST(TrapezoidalMove, LongMoveTakesAccelerationCruiseAndDeceleration) {
  // 10000 steps at 2000 steps/s, 4000 steps/s^2: 0.5 s up (500 steps), 4.5 s cruise, 0.5 s down.
  const TrapezoidalMove m(1.0, 0, 10000, 2000, 4000, 4000);
  EXPECT_NEAR(m.EndTime(), 1.0 + 5.5, 1e-12);
  EXPECT_NEAR(m.PositionAt(1.5), 500, 1e-9);
  EXPECT_NEAR(m.PositionAt(4.0), 500 + 2000 * 2.5, 1e-9);
  EXPECT_NEAR(m.VelocityAt(4.0), 2000, 1e-9);
  EXPECT_EQ(m.PositionAt(100), 10000);
  EXPECT_EQ(m.PositionAt(0.0), 0);  // before it starts
}

TEST(TrapezoidalMove, ShortMoveIsATriangleBelowFullSpeed) {
  // 100 steps cannot reach 2000 steps/s at 4000 steps/s^2: peak sqrt(d a) = sqrt(100 * 4000).
  const TrapezoidalMove m(0, 300, 200, 2000, 4000, 4000);  // backwards
  const double peak = std::sqrt(100.0 * 4000);
  EXPECT_NEAR(m.EndTime(), 2 * peak / 4000, 1e-12);
  EXPECT_NEAR(m.VelocityAt(peak / 4000 - 1e-9), -peak, 1e-3);
  EXPECT_NEAR(m.PositionAt(peak / 4000), 250, 1e-9);  // half-way at the apex
}

TEST(TrapezoidalMove, StopDeceleratesOverVSquaredOverTwoD) {
  const TrapezoidalMove m(0, 0, 100000, 2000, 4000, 8000);
  const TrapezoidalMove s = m.StoppedAt(2.0);  // cruising at 2000 steps/s
  EXPECT_NEAR(s.target() - m.PositionAt(2.0), 2000.0 * 2000 / (2 * 8000), 1e-9);
  EXPECT_NEAR(s.EndTime(), 2.0 + 2000.0 / 8000, 1e-12);
}

class Axis : public ::testing::Test {
 protected:
  void Write32(std::uint16_t a, std::uint32_t v) {
    const std::uint16_t w[2] = {static_cast<std::uint16_t>(v >> 16),
                                static_cast<std::uint16_t>(v & 0xFFFF)};
    axis.Write(a, w, 2);
  }
  std::uint32_t Read32(std::uint16_t a) {
    return (std::uint32_t(axis.Read(a)) << 16) | axis.Read(a + 1);
  }
  bool Status(std::uint32_t bit) { return Read32(kOutputStatus) & bit; }
  // One function-code-16 write of the whole direct-data block, trigger included.
  void DirectData(std::uint32_t type, std::int32_t position, std::uint32_t speed, std::uint32_t acc,
                  std::uint32_t dec) {
    const std::uint32_t v[8] = {0,    type, static_cast<std::uint32_t>(position), speed, acc, dec,
                                1000, 1};
    std::uint16_t w[16];
    for (int k = 0; k < 8; ++k) {
      w[2 * k] = static_cast<std::uint16_t>(v[k] >> 16);
      w[2 * k + 1] = static_cast<std::uint16_t>(v[k] & 0xFFFF);
    }
    axis.Write(kDirectData, w, 16);
  }

  ManualClock clock;
  SimulatedAxis axis{clock};
};

TEST_F(Axis, AbsoluteMoveSetsMoveThenInPositionAfterProfileAndSettling) {
  EXPECT_TRUE(Status(kOutReady));
  DirectData(1, 9000, 3000, 6000, 6000);  // 0.5 s up (750), 2.5 s cruise, 0.5 s down
  EXPECT_TRUE(Status(kOutMove));
  EXPECT_TRUE(Status(kOutBusy));
  EXPECT_FALSE(Status(kOutReady));
  clock.Advance(3.49);
  EXPECT_TRUE(Status(kOutMove));
  clock.Advance(0.02);  // 3.51 s: the profile has ended, settling
  EXPECT_FALSE(Status(kOutMove));
  EXPECT_FALSE(Status(kOutInPos));
  clock.Advance(0.05);
  EXPECT_TRUE(Status(kOutInPos));
  EXPECT_EQ(static_cast<std::int32_t>(Read32(kCommandPosition)), 9000);
}

TEST_F(Axis, IncrementalMovesAddUpAndNegativePositionsRoundTrip) {
  DirectData(2, -1500, 5000, 50000, 50000);
  clock.Advance(5);
  DirectData(2, -1500, 5000, 50000, 50000);
  clock.Advance(5);
  EXPECT_EQ(static_cast<std::int32_t>(Read32(kCommandPosition)), -3000);
}

TEST_F(Axis, TargetBeyondTheSoftLimitRaisesAlarm67AndDoesNotMove) {
  DirectData(1, 250000, 5000, 50000, 50000);  // limit is 200000
  EXPECT_TRUE(Status(kOutAlarm));
  EXPECT_EQ(Read32(kPresentAlarm), kAlarmSoftwareOvertravel);
  EXPECT_FALSE(Status(kOutReady));
  EXPECT_FALSE(axis.Moving());
  DirectData(1, 1000, 5000, 50000, 50000);  // ignored while in alarm
  EXPECT_FALSE(axis.Moving());
  Write32(kAlarmReset, 1);
  EXPECT_FALSE(Status(kOutAlarm));
  EXPECT_EQ(Read32(kPresentAlarm), 0u);
  EXPECT_TRUE(Status(kOutReady));
}

TEST_F(Axis, InvalidOperationDataRaisesAlarm70) {
  DirectData(1, 1000, 0, 50000, 50000);  // speed 0
  EXPECT_EQ(Read32(kPresentAlarm), kAlarmBadData);
  Write32(kInputCommand, kInAlarmReset);  // the input-command path resets too
  EXPECT_EQ(Read32(kPresentAlarm), 0u);
}

TEST_F(Axis, HomingReturnsToZeroAndSetsHomeEnd) {
  EXPECT_FALSE(Status(kOutHomeEnd));  // not homed since power-up
  DirectData(1, 4000, 4000, 40000, 40000);
  clock.Advance(2);
  Write32(kInputCommand, kInHome);
  EXPECT_TRUE(Status(kOutMove));
  clock.Advance(5);
  EXPECT_TRUE(Status(kOutHomeEnd));
  EXPECT_EQ(Read32(kCommandPosition), 0u);
}

TEST_F(Axis, StopDeceleratesAndANewOperationDuringMotionIsIgnored) {
  DirectData(1, 100000, 2000, 4000, 4000);
  clock.Advance(1.0);                      // cruising at 2000 steps/s, at 1500 steps
  DirectData(1, -5000, 2000, 4000, 4000);  // not READY: ignored
  clock.Advance(1.0);                      // 3500 steps
  Write32(kInputCommand, kInStop);
  EXPECT_TRUE(Status(kOutMove));  // still decelerating
  clock.Advance(0.6);
  EXPECT_FALSE(Status(kOutMove));
  // Stopped at 3500 + 2000^2 / (2 * 4000) = 4000 steps.
  EXPECT_EQ(static_cast<std::int32_t>(Read32(kCommandPosition)), 4000);
}

}  // namespace
}  // namespace gonio::sim
