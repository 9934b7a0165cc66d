#include "devices/usbtmc.h"

#include <chrono>
#include <thread>
#include <vector>

namespace gonio::devices {

using namespace usbtmc_msg;

std::array<std::uint8_t, 12> UsbTmcHeader(std::uint8_t msg_id, std::uint8_t tag,
                                          std::uint32_t transfer_size, bool eom) {
  std::array<std::uint8_t, 12> h{};
  h[0] = msg_id;
  h[1] = tag;
  h[2] = static_cast<std::uint8_t>(~tag);
  for (int k = 0; k < 4; ++k) h[4 + k] = static_cast<std::uint8_t>(transfer_size >> (8 * k));
  h[8] = eom ? 0x01 : 0x00;  // bmTransferAttributes: EOM (DEV_DEP_MSG_OUT), TermCharEnabled (in)
  return h;
}

std::uint8_t UsbTmc::NextTag() {
  tag_ = static_cast<std::uint8_t>(tag_ % 255 + 1);  // 1..255: bTag 0 is not allowed
  return tag_;
}

Status UsbTmc::Write(const std::string& message) {
  const std::string payload = message + "\n";
  const auto h = UsbTmcHeader(kDevDepMsgOut, NextTag(), static_cast<std::uint32_t>(payload.size()),
                              /*eom=*/true);
  std::vector<std::uint8_t> out(h.begin(), h.end());
  out.insert(out.end(), payload.begin(), payload.end());
  out.resize((out.size() + 3) / 4 * 4, 0);  // alignment bytes to a multiple of 4
  return t_.BulkOut(out.data(), out.size(), timeout_ms_);
}

Result<std::string> UsbTmc::Read() {
  constexpr std::uint32_t kMax = 4096;
  std::string text;
  for (int part = 0; part < 64; ++part) {  // a long response arrives in several messages
    const std::uint8_t tag = NextTag();
    const auto h = UsbTmcHeader(kRequestDevDepMsgIn, tag, kMax, false);
    if (Status s = t_.BulkOut(h.data(), h.size(), timeout_ms_); !s.ok()) return s.error();
    std::vector<std::uint8_t> in(kHeaderSize + kMax + 3);
    auto got = t_.BulkIn(in.data(), in.size(), timeout_ms_);
    if (!got.ok()) {
      if (got.error().code == ErrorCode::kTimeout) (void)AbortBulkIn(tag);
      return got.error();
    }
    if (*got < kHeaderSize)
      return Error{ErrorCode::kProtocol, "USBTMC: bulk-in transfer of " + std::to_string(*got) +
                                             " bytes is shorter than its header"};
    if (in[0] != kRequestDevDepMsgIn || in[1] != tag || in[2] != static_cast<std::uint8_t>(~tag))
      return Error{ErrorCode::kProtocol,
                   "USBTMC: response header does not answer the request (MsgID " +
                       std::to_string(in[0]) + ", bTag " + std::to_string(in[1]) + ", expected " +
                       std::to_string(tag) + ")"};
    std::uint32_t size = 0;
    for (int k = 0; k < 4; ++k) size |= std::uint32_t(in[4 + k]) << (8 * k);
    if (size > *got - kHeaderSize)
      return Error{ErrorCode::kProtocol,
                   "USBTMC: TransferSize " + std::to_string(size) + " exceeds the bytes received"};
    text.append(reinterpret_cast<const char*>(in.data() + kHeaderSize), size);
    if (in[8] & 0x01) {  // EOM: the message is complete
      while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.pop_back();
      return text;
    }
  }
  return Error{ErrorCode::kProtocol, "USBTMC: response without end of message"};
}

Result<std::string> UsbTmc::Query(const std::string& message) {
  if (Status s = Write(message); !s.ok()) return s.error();
  return Read();
}

Status UsbTmc::AbortBulkIn(std::uint8_t tag) {
  auto r = t_.ClassRequest(usbtmc_request::kInitiateAbortBulkIn, tag, 2, timeout_ms_);
  if (!r.ok()) return r.error();
  for (int i = 0; i < 50; ++i) {  // CHECK_ABORT_BULK_IN_STATUS until no longer pending
    auto c = t_.ClassRequest(usbtmc_request::kCheckAbortBulkInStatus, 0, 8, timeout_ms_);
    if (!c.ok()) return c.error();
    if (!c->empty() && (*c)[0] != kUsbTmcStatusPending) return OkStatus();
  }
  return Error{ErrorCode::kTimeout, "USBTMC: bulk-in abort still pending"};
}

Status UsbTmc::Clear() {
  auto r = t_.ClassRequest(usbtmc_request::kInitiateClear, 0, 1, timeout_ms_);
  if (!r.ok()) return r.error();
  if (r->empty() || (*r)[0] != kUsbTmcStatusSuccess)
    return Error{ErrorCode::kProtocol, "USBTMC: INITIATE_CLEAR refused"};
  // Up to 100 checks 50 ms apart (5 s), as long as the Linux usbtmc driver gives a device.
  for (int i = 0; i < 100; ++i) {
    auto c = t_.ClassRequest(usbtmc_request::kCheckClearStatus, 0, 2, timeout_ms_);
    if (!c.ok()) return c.error();
    if (c->empty()) return Error{ErrorCode::kProtocol, "USBTMC: empty CHECK_CLEAR_STATUS answer"};
    // Done: the device halted bulk-out when the clear began; the host clears that halt.
    if ((*c)[0] == kUsbTmcStatusSuccess) return t_.ClearHalt(UsbTmcEndpoint::kBulkOut);
    if ((*c)[0] != kUsbTmcStatusPending)
      return Error{ErrorCode::kProtocol,
                   "USBTMC: CHECK_CLEAR_STATUS answered status " + std::to_string((*c)[0])};
    if (c->size() > 1 && ((*c)[1] & 0x01)) {
      // bmClear.D0: bulk-in holds data the device could not drop; read it to a short packet.
      std::vector<std::uint8_t> junk(4096);
      for (int k = 0; k < 64; ++k) {
        auto got = t_.BulkIn(junk.data(), junk.size(), timeout_ms_);
        if (!got.ok() || *got < junk.size()) break;
      }
    } else {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }
  return Error{ErrorCode::kTimeout, "USBTMC: clear still pending"};
}

}  // namespace gonio::devices
