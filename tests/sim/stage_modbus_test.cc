// The simulated stage controller over real Modbus TCP on 127.0.0.1: a libmodbus client (what the
// driver of #5 will be) moves an axis through the documented registers, and errors arrive as the
// Modbus exceptions a real gateway sends.
#include <gtest/gtest.h>
#include <modbus/modbus.h>

#include <cerrno>
#include <cstdint>

#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/stage/axis.h"
#include "sim/stage/modbus_rtu_server.h"
#include "sim/stage/modbus_tcp_server.h"

namespace gonio::sim {
namespace {

using namespace stage_reg;

class StageModbusTcp : public ::testing::Test {
 protected:
  void SetUp() override {
    auto s = StageModbusTcpServer::Start({&axis1, &axis2});
    ASSERT_TRUE(s.ok()) << s.error().message;
    server = std::move(*s);
    ASSERT_GT(server->port(), 0);
    client = modbus_new_tcp("127.0.0.1", server->port());
    ASSERT_NE(client, nullptr);
    modbus_set_response_timeout(client, 2, 0);
    ASSERT_EQ(modbus_connect(client), 0) << modbus_strerror(errno);
  }
  void TearDown() override {
    if (client) {
      modbus_close(client);
      modbus_free(client);
    }
  }
  std::uint32_t Read32(int unit, std::uint16_t address) {
    modbus_set_slave(client, unit);
    std::uint16_t r[2] = {0, 0};
    EXPECT_EQ(modbus_read_registers(client, address, 2, r), 2) << modbus_strerror(errno);
    return (std::uint32_t(r[0]) << 16) | r[1];
  }

  ManualClock clock;
  SimulatedAxis axis1{clock}, axis2{clock};
  std::unique_ptr<StageModbusTcpServer> server;
  modbus_t* client = nullptr;
};

TEST_F(StageModbusTcp, ClientMovesAnAxisThroughTheDocumentedRegisters) {
  // One function-code-16 write of the direct-data block to unit 2: absolute 12000 steps at
  // 4000 steps/s, 40000 steps/s^2, trigger.
  const std::uint32_t v[8] = {0, 1, 12000, 4000, 40000, 40000, 1000, 1};
  std::uint16_t w[16];
  for (int k = 0; k < 8; ++k) {
    w[2 * k] = static_cast<std::uint16_t>(v[k] >> 16);
    w[2 * k + 1] = static_cast<std::uint16_t>(v[k] & 0xFFFF);
  }
  modbus_set_slave(client, 2);
  ASSERT_EQ(modbus_write_registers(client, kDirectData, 16, w), 16) << modbus_strerror(errno);
  EXPECT_TRUE(Read32(2, kOutputStatus) & kOutMove);
  EXPECT_FALSE(Read32(1, kOutputStatus) & kOutMove);  // the other axis is untouched
  clock.Advance(3.2 + 0.06);  // 0.1 s up, 2.9 s cruise, 0.1 s down, settle 0.05 s
  const std::uint32_t status = Read32(2, kOutputStatus);
  EXPECT_FALSE(status & kOutMove);
  EXPECT_TRUE(status & kOutInPos);
  EXPECT_EQ(static_cast<std::int32_t>(Read32(2, kCommandPosition)), 12000);
  // A single-register write (function code 6) of the STOP/ALM-RST word works as well.
  modbus_set_slave(client, 2);
  EXPECT_EQ(modbus_write_register(client, kInputCommand + 1, kInStop), 1);
}

TEST_F(StageModbusTcp, ErrorsAreModbusExceptions) {
  std::uint16_t r[2];
  modbus_set_slave(client, 1);
  EXPECT_EQ(modbus_read_registers(client, 0x0300, 1, r), -1);  // outside the map
  EXPECT_EQ(errno, EMBXILADD);
  modbus_set_slave(client, 9);  // no such axis
  EXPECT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), -1);
  EXPECT_EQ(errno, EMBXGTAR);
  // The connection survives both.
  EXPECT_TRUE(Read32(1, kOutputStatus) & kOutReady);
}

TEST_F(StageModbusTcp, SoftLimitAlarmIsVisibleAndResettableOverTheWire) {
  modbus_set_slave(client, 1);
  const std::uint16_t w[16] = {0,     0, 0,    1, 0x0004, 0x93E0 /* 300000 */, 0, 4000, 0, 40000, 0,
                               40000, 0, 1000, 0, 1};
  ASSERT_EQ(modbus_write_registers(client, kDirectData, 16, w), 16);
  EXPECT_TRUE(Read32(1, kOutputStatus) & kOutAlarm);
  EXPECT_EQ(Read32(1, kPresentAlarm), kAlarmSoftwareOvertravel);
  const std::uint16_t reset[2] = {0, 1};
  modbus_set_slave(client, 1);
  ASSERT_EQ(modbus_write_registers(client, kAlarmReset, 2, reset), 2);
  EXPECT_EQ(Read32(1, kPresentAlarm), 0u);
}

// Fault plan over TCP: a request with no reply (the client's timeout), then a dropped connection
// that the client sees and recovers from by reconnecting.
TEST(StageModbusTcpFaults, TimeoutAndDropReachTheClientAsFromRealHardware) {
  ManualClock clock;
  SimulatedAxis axis(clock, {}, "arm");
  FaultPlan plan(
      {OnOpportunity(FaultKind::kModbusTimeout, 2), OnOpportunity(FaultKind::kModbusDrop, 4)}, 1);
  auto server = StageModbusTcpServer::Start({&axis}, 0, &plan, &clock);
  ASSERT_TRUE(server.ok()) << server.error().message;
  modbus_t* c = modbus_new_tcp("127.0.0.1", (*server)->port());
  ASSERT_EQ(modbus_connect(c), 0);
  modbus_set_slave(c, 1);
  modbus_set_response_timeout(c, 0, 300'000);
  std::uint16_t r[2];
  EXPECT_EQ(modbus_read_registers(c, kOutputStatus, 2, r), 2);   // 1: fine
  EXPECT_EQ(modbus_read_registers(c, kOutputStatus, 2, r), -1);  // 2: no reply
  EXPECT_EQ(errno, ETIMEDOUT);
  EXPECT_EQ(modbus_read_registers(c, kOutputStatus, 2, r), 2);   // 3: fine again
  EXPECT_EQ(modbus_read_registers(c, kOutputStatus, 2, r), -1);  // 4: the connection closes
  EXPECT_NE(errno, ETIMEDOUT);
  modbus_close(c);
  ASSERT_EQ(modbus_connect(c), 0);  // a reconnect works
  EXPECT_EQ(modbus_read_registers(c, kOutputStatus, 2, r), 2);
  modbus_close(c);
  modbus_free(c);
  EXPECT_EQ(plan.Fired().size(), 2u);
}

class StageModbusRtu : public ::testing::Test {
 protected:
  void Open(FaultPlan* plan = nullptr) {
    auto s = StageModbusRtuServer::Start({&axis1, &axis2}, {}, plan, &clock);
    ASSERT_TRUE(s.ok()) << s.error().message;
    server = std::move(*s);
    // What the driver's RTU backend does: any line settings (a pty ignores them).
    client = modbus_new_rtu(server->pty_path().c_str(), 115200, 'E', 8, 1);
    ASSERT_NE(client, nullptr);
    modbus_set_response_timeout(client, 0, 300'000);
    ASSERT_EQ(modbus_connect(client), 0) << modbus_strerror(errno);
  }
  void TearDown() override {
    if (client) {
      modbus_close(client);
      modbus_free(client);
    }
  }
  ManualClock clock;
  SimulatedAxis axis1{clock, {}, "sample"}, axis2{clock, {}, "arm"};
  std::unique_ptr<StageModbusRtuServer> server;
  modbus_t* client = nullptr;
};

TEST(ModbusCrc16, MatchesTheStandardCheckValue) {
  const std::uint8_t msg[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
  EXPECT_EQ(ModbusCrc16(msg, sizeof msg), 0x4B37);  // CRC-16/MODBUS check value
}

TEST_F(StageModbusRtu, ClientMovesTheSecondSlaveOnTheLine) {
  Open();
  const std::uint16_t w[16] = {0, 0, 0, 1, 0, 8000, 0, 4000, 0, 40000, 0, 40000, 0, 1000, 0, 1};
  modbus_set_slave(client, 2);
  ASSERT_EQ(modbus_write_registers(client, kDirectData, 16, w), 16) << modbus_strerror(errno);
  std::uint16_t r[2];
  ASSERT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), 2) << modbus_strerror(errno);
  EXPECT_TRUE(r[1] & kOutMove);
  clock.Advance(3);
  ASSERT_EQ(modbus_read_registers(client, kCommandPosition, 2, r), 2);
  EXPECT_EQ((r[0] << 16) | r[1], 8000);
  EXPECT_EQ(axis1.MotorSteps(), 0);  // slave 1 untouched
  // An address outside the map: exception 0x02, as from the real driver.
  EXPECT_EQ(modbus_read_registers(client, 0x0300, 1, r), -1);
  EXPECT_EQ(errno, EMBXILADD);
  // A slave that is not on the line: silence, so the client times out.
  modbus_set_slave(client, 7);
  EXPECT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), -1);
  EXPECT_EQ(errno, ETIMEDOUT);
}

TEST_F(StageModbusRtu, FaultPlanCorruptsACrcAndSilencesAReply) {
  FaultPlan plan({OnOpportunity(FaultKind::kModbusCrc, 1, "sample"),
                  OnOpportunity(FaultKind::kModbusTimeout, 3, "sample")},
                 1);
  Open(&plan);
  modbus_set_slave(client, 1);
  std::uint16_t r[2];
  EXPECT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), -1);
  EXPECT_EQ(errno, EMBBADCRC);
  modbus_flush(client);
  EXPECT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), 2) << modbus_strerror(errno);
  EXPECT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), -1);
  EXPECT_EQ(errno, ETIMEDOUT);
  EXPECT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), 2);
  modbus_set_slave(client, 2);  // the other axis was never targeted
  EXPECT_EQ(modbus_read_registers(client, kOutputStatus, 2, r), 2);
}

}  // namespace
}  // namespace gonio::sim
