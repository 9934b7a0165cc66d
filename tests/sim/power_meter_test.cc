// The simulated source monitor under the driver's own USBTMC framing and SCPI meter
// (devices/usbtmc.h, devices/scpi_power_meter.h): the bytes on the bulk endpoints, the SCPI command
// set and error queue, a timed-out read recovered by the class abort request, a disconnect and
// reopen from the fault plan, and readings that follow the lamp.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "backends/usbtmc_socket.h"
#include "daemon/instrument/instrument.h"
#include "devices/scpi_power_meter.h"
#include "devices/usbtmc.h"
#include "sim/clock.h"
#include "sim/monitor/monitor_server.h"
#include "sim/monitor/power_meter.h"

namespace gonio::sim {
namespace {

using devices::ScpiPowerMeter;
using devices::UsbTmc;

class PowerMeter : public ::testing::Test {
 protected:
  ManualClock clock;
  Lamp lamp{LampOptions{
      .nominal_w = 2e-3, .drift_per_hour = 0.01, .wander_amplitude = 0, .flicker_rms = 0}};
};

TEST_F(PowerMeter, BulkOutMessageIsTheUsbTmcHeaderAndPaddedPayload) {
  // The framing's bytes, checked against USBTMC 1.0 table 3 by hand: MsgID 1, bTag 1, ~bTag,
  // reserved, TransferSize 6 little-endian, EOM, 3 reserved; "*IDN?\n" padded to 8 bytes.
  const auto h = devices::UsbTmcHeader(1, 1, 6, true);
  const std::array<std::uint8_t, 12> expected{1, 1, 0xFE, 0, 6, 0, 0, 0, 1, 0, 0, 0};
  EXPECT_EQ(h, expected);
  SimulatedPowerMeter dev(clock, lamp);
  UsbTmc tmc(dev);
  auto idn = tmc.Query("*IDN?");
  ASSERT_TRUE(idn.ok()) << idn.error().message;
  EXPECT_EQ(*idn, "gonio-sim,PM100USB (simulated),SIM-PM-1,1.0.0");
  EXPECT_EQ(tmc.last_tag(), 2);  // one tag for the command, one for the read request
}

TEST_F(PowerMeter, TagsWrapFrom255ToOneNeverZero) {
  SimulatedPowerMeter dev(clock, lamp);
  UsbTmc tmc(dev);
  for (int i = 0; i < 200; ++i) ASSERT_TRUE(tmc.Query("SENS:AVER:COUN?").ok()) << i;
  EXPECT_EQ(tmc.last_tag(), 400 % 255);  // 400 tags used: wrapped once past 255, skipping 0
}

TEST_F(PowerMeter, ScpiSettingsAndTheErrorQueue) {
  SimulatedPowerMeter dev(clock, lamp);
  ScpiPowerMeter meter(dev);
  EXPECT_TRUE(meter.SetWavelengthNm(850).ok());
  EXPECT_EQ(dev.wavelength_nm(), 850);
  EXPECT_TRUE(meter.SetAveraging(100).ok());
  EXPECT_EQ(dev.averaging(), 100);
  // Out of range: the meter's own SCPI error reaches the operator.
  const Status bad = meter.SetWavelengthNm(2000);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("-222"), std::string::npos) << bad.error().message;
  EXPECT_EQ(dev.wavelength_nm(), 850);  // unchanged
  // Long forms and lower case are SCPI too.
  UsbTmc tmc(dev);
  EXPECT_EQ(*tmc.Query("sense:average:count?"), "100");
  ASSERT_TRUE(tmc.Write("SENS:BOGUS 3").ok());
  EXPECT_EQ(*tmc.Query("SYST:ERR?"), "-113,\"Undefined header\"");
  EXPECT_EQ(*tmc.Query("SYST:ERR?"), "0,\"No error\"");
  // A command before the last response was read: IEEE 488.2's query INTERRUPTED (-410), and the
  // unread response is gone.
  ASSERT_TRUE(tmc.Write("MEAS:POW?").ok());
  EXPECT_EQ(*tmc.Query("SYST:ERR?"), "-410,\"Query INTERRUPTED\"");
  EXPECT_EQ(*tmc.Query("SYST:ERR?"), "0,\"No error\"");
}

TEST_F(PowerMeter, ReadingsFollowTheLampAndAveragingNarrowsTheNoise) {
  SimulatedPowerMeter dev(clock, lamp, PowerMeterOptions{.noise_rel = 1e-3});
  ScpiPowerMeter meter(dev);
  clock.Advance(1);
  auto stats = [&](int n) {
    double s = 0, s2 = 0;
    for (int i = 0; i < n; ++i) {
      const double w = *meter.PowerW();
      s += w, s2 += w * w;
    }
    return std::pair{s / n, std::sqrt(std::max(0.0, s2 / n - (s / n) * (s / n)))};
  };
  const auto [mean1, sd1] = stats(400);
  EXPECT_NEAR(mean1, lamp.PowerW(1), 5 * sd1 / 20);
  EXPECT_NEAR(sd1 / mean1, 1e-3, 2e-4);
  ASSERT_TRUE(meter.SetAveraging(100).ok());
  const auto [mean100, sd100] = stats(400);
  EXPECT_NEAR(sd100 / mean100, 1e-4, 2e-5);  // 1/sqrt(100)
  // Two hours of drift at 1 %/h: the reading follows.
  clock.Advance(7200);
  const auto [mean_later, sd_later] = stats(100);
  EXPECT_NEAR(mean_later / mean100, lamp.Relative(7201) / lamp.Relative(1), 1e-4);
  EXPECT_GT(mean_later / mean100, 1.015);
}

TEST_F(PowerMeter, TimedOutReadIsAbortedAndTheNextQueryIsClean) {
  SimulatedPowerMeter dev(clock, lamp);
  UsbTmc tmc(dev, 100);
  ASSERT_TRUE(tmc.Write("SENS:CORR:WAV 700").ok());  // a command with no response
  auto r = tmc.Read();                               // ... read anyway: the device NAKs
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kTimeout);
  EXPECT_EQ(*tmc.Query("SENS:CORR:WAV?"), "700.0");
  // A response left unread is discarded by the abort of the next timed-out read, or by Clear.
  ASSERT_TRUE(tmc.Write("*IDN?").ok());
  ASSERT_TRUE(tmc.Clear().ok());
  EXPECT_EQ(*tmc.Query("SENS:AVER:COUN?"), "1");
}

TEST_F(PowerMeter, DisconnectFromTheFaultPlanAndReopenAfterItReturns) {
  FaultEvent away = OnOpportunity(FaultKind::kMonitorDisconnect, 3);
  away.duration_s = 5;
  FaultPlan plan({away}, 1);
  SimulatedPowerMeter dev(clock, lamp, {}, 1, &plan);
  ScpiPowerMeter meter(dev);
  ASSERT_TRUE(meter.PowerW().ok());  // bulk-outs 1 and 2
  auto r = meter.PowerW();           // bulk-out 3: the meter leaves; the reopen fails too
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotConnected);
  EXPECT_NE(r.error().message.find("reopen failed"), std::string::npos) << r.error().message;
  clock.Advance(6);  // back on the bus: the meter reopens it and answers
  auto again = meter.PowerW();
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_NEAR(*again, lamp.PowerW(6), 1e-3 * lamp.PowerW(6));
}

// The device side on its own, with bytes written here from USBTMC 1.0 (tables 3, 4 and 9), not
// by either side's framing code: a query, and its answer split by the host's TransferSize.
TEST_F(PowerMeter, AnswersHandBuiltTransfersAndSplitsAResponseAtTheRequestedSize) {
  SimulatedPowerMeter dev(clock, lamp);
  // DEV_DEP_MSG_OUT, bTag 7, TransferSize 6, EOM; "*IDN?\n" padded to 8.
  const std::uint8_t query[20] = {1, 7, 0xF8, 0,   6,   0,   0,   0,    1, 0,
                                  0, 0, '*',  'I', 'D', 'N', '?', '\n', 0, 0};
  ASSERT_TRUE(dev.BulkOut(query, sizeof query, 100).ok());
  // REQUEST_DEV_DEP_MSG_IN, bTag 8, at most 8 bytes.
  const std::uint8_t request8[12] = {2, 8, 0xF7, 0, 8, 0, 0, 0, 0, 0, 0, 0};
  ASSERT_TRUE(dev.BulkOut(request8, sizeof request8, 100).ok());
  std::uint8_t in[64] = {};
  auto n = dev.BulkIn(in, sizeof in, 100);
  ASSERT_TRUE(n.ok()) << n.error().message;
  ASSERT_EQ(*n, 12u + 8u);  // header and 8 bytes, already a multiple of 4
  EXPECT_EQ(in[0], 2);      // DEV_DEP_MSG_IN
  EXPECT_EQ(in[1], 8);
  EXPECT_EQ(in[2], 0xF7);
  EXPECT_EQ(in[4] | in[5] << 8 | in[6] << 16 | in[7] << 24, 8);
  EXPECT_EQ(in[8] & 1, 0);  // not the end of the message
  std::string answer(reinterpret_cast<const char*>(in + 12), 8);
  // The rest, in one transfer with EOM set and padded to 4 bytes.
  const std::uint8_t request_all[12] = {2, 9, 0xF6, 0, 64, 0, 0, 0, 0, 0, 0, 0};
  ASSERT_TRUE(dev.BulkOut(request_all, sizeof request_all, 100).ok());
  n = dev.BulkIn(in, sizeof in, 100);
  ASSERT_TRUE(n.ok()) << n.error().message;
  const std::uint32_t size = in[4] | in[5] << 8 | in[6] << 16 | in[7] << 24;
  EXPECT_EQ(in[1], 9);
  EXPECT_EQ(in[8] & 1, 1);
  EXPECT_EQ(*n % 4, 0u);
  ASSERT_GE(*n, 12u + size);
  answer.append(reinterpret_cast<const char*>(in + 12), size);
  EXPECT_EQ(answer, "gonio-sim,PM100USB (simulated),SIM-PM-1,1.0.0\n");
}

TEST_F(PowerMeter, MalformedHeaderStallsTheEndpoint) {
  SimulatedPowerMeter dev(clock, lamp);
  const std::uint8_t bad[12] = {1, 5, 5, 0, 0, 0, 0, 0, 1, 0, 0, 0};  // ~bTag wrong
  const Status s = dev.BulkOut(bad, sizeof bad, 100);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("LIBUSB_ERROR_PIPE"), std::string::npos);
}

// Another process's view: the same framing and SCPI over the loopback socket transport, errors
// (here a disconnect from the fault plan) carried with their codes.
TEST_F(PowerMeter, OverTheLoopbackSocketTheDriverSeesTheSameMeter) {
  FaultEvent away = OnOpportunity(FaultKind::kMonitorDisconnect, 6);
  away.duration_s = 1;
  FaultPlan plan({away}, 1);
  SimulatedPowerMeter dev(clock, lamp, {}, 1, &plan);
  auto server = MonitorSocketServer::Start(dev);
  ASSERT_TRUE(server.ok()) << server.error().message;
  auto transport = backends::UsbTmcSocketTransport::Connect("127.0.0.1", (*server)->port());
  ASSERT_TRUE(transport.ok()) << transport.error().message;
  ScpiPowerMeter meter(**transport);
  auto idn = meter.Identity();
  ASSERT_TRUE(idn.ok()) << idn.error().message;
  EXPECT_EQ(idn->rfind("gonio-sim,PM100USB", 0), 0u);
  ASSERT_TRUE(meter.SetAveraging(10).ok());  // bulk-outs 3, 4 and 5 (command, SYST:ERR?, read)
  auto r = meter.PowerW();                   // bulk-out 6: the meter leaves the bus
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotConnected);
  clock.Advance(2);
  EXPECT_TRUE(meter.PowerW().ok());
  EXPECT_FALSE(backends::UsbTmcSocketTransport::Connect("localhost", 1).ok());  // numeric only
}

// Issue #18: the process serving the meter ends and a new one serves it on the same port (a
// gonio-sim restart). The driver's reopen dials again; it used to send its reopen down the dead
// socket and never recover.
TEST_F(PowerMeter, AServerThatRestartsOnItsPortIsReachedAgain) {
  SimulatedPowerMeter dev(clock, lamp, {}, 1, nullptr);
  auto server = MonitorSocketServer::Start(dev);
  ASSERT_TRUE(server.ok()) << server.error().message;
  const int port = (*server)->port();
  auto transport = backends::UsbTmcSocketTransport::Connect("127.0.0.1", port);
  ASSERT_TRUE(transport.ok()) << transport.error().message;
  ScpiPowerMeter meter(**transport);
  ASSERT_TRUE(meter.PowerW().ok());
  server->reset();  // the process is gone
  auto gone = meter.PowerW();
  ASSERT_FALSE(gone.ok());
  EXPECT_EQ(gone.error().code, ErrorCode::kNotConnected) << gone.error().message;
  auto again = MonitorSocketServer::Start(dev, port);  // back, on its port
  ASSERT_TRUE(again.ok()) << again.error().message;
  auto back = meter.PowerW();
  EXPECT_TRUE(back.ok()) << back.error().message;
}

// USBTMC 1.0 table 32: INITIATE_CLEAR halts bulk-out and drops both buffers; the host clears the
// halt once CHECK_CLEAR_STATUS says done (section 4.2.1.7). A driver that skips that step cannot
// send again.
TEST_F(PowerMeter, AClearHaltsBulkOutUntilTheHostClearsTheHalt) {
  SimulatedPowerMeter dev(clock, lamp);
  UsbTmc tmc(dev);
  ASSERT_TRUE(tmc.Write("MEAS:POW?").ok());
  auto begun = dev.ClassRequest(devices::usbtmc_request::kInitiateClear, 0, 1, 1000);
  ASSERT_TRUE(begun.ok()) << begun.error().message;
  EXPECT_EQ((*begun)[0], devices::kUsbTmcStatusSuccess);
  const Status halted = tmc.Write("*IDN?");
  ASSERT_FALSE(halted.ok());
  EXPECT_NE(halted.error().message.find("LIBUSB_ERROR_PIPE"), std::string::npos);
  ASSERT_TRUE(dev.ClearHalt(devices::UsbTmcEndpoint::kBulkOut).ok());
  auto idn = tmc.Query("*IDN?");  // the reading left before the clear is gone
  ASSERT_TRUE(idn.ok()) << idn.error().message;
  EXPECT_EQ(idn->rfind("gonio-sim,", 0), 0u) << *idn;
  // The framing's own Clear does all of it.
  ASSERT_TRUE(tmc.Write("MEAS:POW?").ok());
  ASSERT_TRUE(tmc.Clear().ok());
  auto again = tmc.Query("*IDN?");
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(again->rfind("gonio-sim,", 0), 0u) << *again;
}

// A device that cannot drop its bulk-in data itself answers CHECK_CLEAR_STATUS with PENDING and
// bmClear.D0 set: the host reads bulk-in to a short packet and asks again (section 4.2.1.7). Our
// simulated meter never does; a real one may. A FAILED status is an error, not a done clear.
class ScriptedClear final : public devices::UsbTmcTransport {
 public:
  explicit ScriptedClear(std::uint8_t final_status) : final_(final_status) {}
  Status BulkOut(const std::uint8_t*, std::size_t, int) override { return OkStatus(); }
  Result<std::size_t> BulkIn(std::uint8_t*, std::size_t capacity, int) override {
    ++bulk_in_reads;
    return bulk_in_left > 0 ? (--bulk_in_left, capacity) : std::size_t{12};  // full, then short
  }
  Result<std::vector<std::uint8_t>> ClassRequest(std::uint8_t request, std::uint16_t, std::uint16_t,
                                                 int) override {
    if (request == devices::usbtmc_request::kInitiateClear) return std::vector<std::uint8_t>{1};
    if (request != devices::usbtmc_request::kCheckClearStatus)
      return Error{ErrorCode::kIo, "unexpected request"};
    if (++checks == 1) return std::vector<std::uint8_t>{devices::kUsbTmcStatusPending, 0x01};
    return std::vector<std::uint8_t>{final_, 0x00};
  }
  Status ClearHalt(devices::UsbTmcEndpoint e) override {
    if (e == devices::UsbTmcEndpoint::kBulkOut) ++out_halts_cleared;
    return OkStatus();
  }
  Status Reopen() override { return OkStatus(); }

  int checks = 0, bulk_in_reads = 0, bulk_in_left = 1, out_halts_cleared = 0;

 private:
  std::uint8_t final_;
};

TEST(UsbTmcClear, DrainsBulkInWhenTheDeviceAsksAndClearsTheHaltWhenDone) {
  ScriptedClear device(devices::kUsbTmcStatusSuccess);
  UsbTmc tmc(device);
  const Status s = tmc.Clear();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(device.checks, 2);
  EXPECT_EQ(device.bulk_in_reads, 2);  // a full transfer, then the short one that ends it
  EXPECT_EQ(device.out_halts_cleared, 1);

  ScriptedClear failing(devices::kUsbTmcStatusFailed);
  UsbTmc tmc2(failing);
  const Status f = tmc2.Clear();
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.error().message.find("CHECK_CLEAR_STATUS"), std::string::npos) << f.error().message;
  EXPECT_EQ(failing.out_halts_cleared, 0);
}

// A meter outlives its clients: a process killed between a query's request and its read (the
// kill-and-resume test's SIGKILL did this in CI) leaves the response queued, and an earlier
// mistake leaves an entry in the error queue. The next session's first setting read whatever was
// left - the stale reading (CI: "refused 'SENS:CORR:WAV 633': 1.203293E-03"), an old error, or
// the -410 that a 488.2 meter queues when it drops the unread response - and refused to open.
// Opening now clears the meter first.
TEST_F(PowerMeter, OpeningTheMonitorStartsCleanAfterAClientThatDiedMidQuery) {
  SimulatedPowerMeter dev(clock, lamp, {}, 1, nullptr);
  auto server = MonitorSocketServer::Start(dev);
  ASSERT_TRUE(server.ok()) << server.error().message;
  auto leave_stale = [&] {
    auto earlier = backends::UsbTmcSocketTransport::Connect("127.0.0.1", (*server)->port());
    ASSERT_TRUE(earlier.ok()) << earlier.error().message;
    UsbTmc tmc(**earlier);
    ASSERT_TRUE(tmc.Write("SENS:BOGUS 1").ok());  // -113 in the error queue
    ASSERT_TRUE(tmc.Write("MEAS:POW?").ok());     // a response nobody reads
  };  // the earlier client's socket closes here, as a killed process's would

  // Without the clear the hazard is real: what the earlier client left fails a setting's check.
  leave_stale();
  {
    auto t = backends::UsbTmcSocketTransport::Connect("127.0.0.1", (*server)->port());
    ASSERT_TRUE(t.ok()) << t.error().message;
    ScpiPowerMeter unclear(**t);
    EXPECT_FALSE(unclear.SetWavelengthNm(633).ok());
  }

  leave_stale();
  config::InstrumentConfig c;
  c.monitor.enabled = true;
  c.monitor.transport = config::MonitorTransport::kSocket;
  c.monitor.port = (*server)->port();
  c.monitor.wavelength_nm = 700;
  c.monitor.averaging = 10;
  auto opened = daemon::OpenMonitor(c);
  ASSERT_TRUE(opened.ok()) << opened.error().message;
  EXPECT_EQ(dev.wavelength_nm(), 700);
  EXPECT_EQ(dev.averaging(), 10);
  auto w = opened->monitor->PowerW();
  ASSERT_TRUE(w.ok()) << w.error().message;
  EXPECT_NEAR(*w, 2e-3, 1e-5);  // a reading of its own, near the lamp's 2 mW
  ScpiPowerMeter check(*opened->transport);
  auto first_error = check.NextError();
  ASSERT_TRUE(first_error.ok()) << first_error.error().message;
  EXPECT_EQ(*first_error, "0,\"No error\"");  // the earlier -113 is gone
}

}  // namespace
}  // namespace gonio::sim
