// Modbus TCP replies from the controller's side: whatever a stage controller answers - register
// values no real controller would hold (alarm codes, positions at the ends of 32 bits, every
// status bit), exceptions, frames with the wrong transaction, length or function, bytes that are
// no frame at all - the stage driver (backends/modbus_stage.cc over libmodbus) opens, reads,
// moves, homes and stops with a result or an error, never a crash, undefined behaviour or a hang.
//
// The controller is a loopback server written here from the Modbus TCP framing (MBAP header,
// functions 0x03 and 0x10), not libmodbus's. The input is a list of replies, each
// [mode][length][length bytes]; each request the driver sends takes the next:
//   mode % 4 == 0  a well-formed reply; a read's registers are the bytes, repeated
//              1   the bytes as they are, for the whole reply
//              2   a Modbus exception, code = the first byte
//              3   a well-formed reply with one header field wrong (chosen by the first byte)
// Once the input is used up every request gets exception 4 (server device failure), which the
// driver does not retry, so each input ends quickly.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "backends/modbus_stage.h"

namespace {

struct Reply {
  std::uint8_t mode = 0;
  std::vector<std::uint8_t> bytes;
};

class FakeController {
 public:
  FakeController() {
    listen_fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    const int one = 1;
    ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);  // loopback only
    socklen_t len = sizeof a;
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
        ::listen(listen_fd_, 4) != 0 ||
        ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
      std::perror("modbus_reply_fuzz: cannot listen on loopback");
      std::abort();
    }
    port_ = ntohs(a.sin_port);
    std::thread([this] { Serve(); }).detach();  // for the process's life
  }
  int port() const { return port_; }

  void Feed(const std::uint8_t* data, std::size_t size) {
    std::lock_guard lock(mu_);
    replies_.clear();
    for (std::size_t i = 0; i + 1 < size;) {
      Reply r;
      r.mode = data[i];
      const std::size_t n = std::min<std::size_t>(data[i + 1], size - i - 2);
      r.bytes.assign(data + i + 2, data + i + 2 + n);
      replies_.push_back(std::move(r));
      i += 2 + n;
    }
  }

 private:
  static bool ReadAll(int fd, std::uint8_t* out, std::size_t n) {
    return n == 0 || ::recv(fd, out, n, MSG_WAITALL) == static_cast<ssize_t>(n);
  }

  void Serve() {
    for (;;) {
      const int fd = ::accept(listen_fd_, nullptr, nullptr);
      if (fd < 0) continue;
      std::uint8_t head[7], pdu[260];
      while (ReadAll(fd, head, 7)) {
        const std::size_t len = (head[4] << 8) | head[5];
        if (len < 2 || len > sizeof pdu + 1 || !ReadAll(fd, pdu, len - 1)) break;
        const std::vector<std::uint8_t> out = Answer(head, pdu, len - 1);
        if (!out.empty() && ::send(fd, out.data(), out.size(), MSG_NOSIGNAL) < 0) break;
      }
      ::close(fd);
    }
  }

  // The reply to one request (MBAP header `head`, PDU `pdu` of n bytes).
  std::vector<std::uint8_t> Answer(const std::uint8_t* head, const std::uint8_t* pdu,
                                   std::size_t n) {
    Reply r;
    {
      std::lock_guard lock(mu_);
      if (replies_.empty()) {
        r.mode = 2;
        r.bytes = {4};
      } else {
        r = std::move(replies_.front());
        replies_.pop_front();
      }
    }
    const std::uint8_t fc = pdu[0];
    std::vector<std::uint8_t> body;  // the reply's PDU
    switch (r.mode % 4) {
      case 1:
        return r.bytes;
      case 2:
        body = {static_cast<std::uint8_t>(fc | 0x80),
                r.bytes.empty() ? std::uint8_t{1} : r.bytes[0]};
        break;
      default:
        if (fc == 0x03 && n >= 5) {
          const int count = std::min((pdu[3] << 8) | pdu[4], 125);
          body = {fc, static_cast<std::uint8_t>(2 * count)};
          for (int k = 0; k < 2 * count; ++k)
            body.push_back(r.bytes.empty() ? 0 : r.bytes[k % r.bytes.size()]);
        } else if (fc == 0x10 && n >= 5) {
          body.assign(pdu, pdu + 5);  // function, address, count: the write's echo
        } else {
          body = {static_cast<std::uint8_t>(fc | 0x80), 1};  // illegal function
        }
    }
    std::vector<std::uint8_t> out(head, head + 7);
    const std::size_t len = body.size() + 1;
    out[4] = static_cast<std::uint8_t>(len >> 8);
    out[5] = static_cast<std::uint8_t>(len);
    out.insert(out.end(), body.begin(), body.end());
    if (r.mode % 4 == 3 && !r.bytes.empty()) {
      // One field wrong: transaction, protocol, length, unit, function or byte count.
      const std::size_t at[] = {1, 3, 5, 6, 7, 8};
      const std::size_t i = at[r.bytes[0] % 6];
      if (i < out.size()) out[i] = static_cast<std::uint8_t>(out[i] + 1 + r.bytes.size());
    }
    return out;
  }

  int listen_fd_ = -1;
  int port_ = 0;
  std::mutex mu_;
  std::deque<Reply> replies_;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static FakeController* controller = new FakeController;  // serves for the process's life
  controller->Feed(data, size);
  gonio::devices::ModbusLink link;
  link.host = "127.0.0.1";
  link.port = controller->port();
  link.response_timeout_s = 0.005;  // a short or missing reply costs 5 ms, not the default 0.5 s
  link.retries = 1;
  gonio::devices::AxisSettings sample{.name = "sample", .slave_id = 1};
  sample.min_deg = -80, sample.max_deg = 80, sample.backlash_overshoot_deg = 0.5;
  sample.move_timeout_s = sample.home_timeout_s = 0.01;
  gonio::devices::AxisSettings arm{.name = "arm", .slave_id = 2};
  arm.min_deg = 0, arm.max_deg = 360, arm.steps_per_degree = 1e6, arm.degrees_at_zero = 180;
  arm.move_timeout_s = arm.home_timeout_s = 0.01;
  auto opened = gonio::backends::ModbusStageController::Open(link, {sample, arm});
  if (!opened.ok()) return 0;
  auto& stages = **opened;
  (void)stages.ReadStatus("sample");
  (void)stages.ReadStatus("arm");
  (void)stages.MoveTo({{"sample", 10}, {"arm", 181.5}});
  (void)stages.Home({"arm"});
  (void)stages.ResetAlarm("sample");
  (void)stages.StopAll();
  return 0;
}
