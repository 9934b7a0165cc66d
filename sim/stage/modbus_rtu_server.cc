#include "sim/stage/modbus_rtu_server.h"

#include <fcntl.h>
#include <modbus/modbus.h>
#include <pty.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <vector>

#include "sim/stage/modbus_reply.h"

namespace gonio::sim {

std::uint16_t ModbusCrc16(const std::uint8_t* data, std::size_t length) {
  std::uint16_t crc = 0xFFFF;
  for (std::size_t i = 0; i < length; ++i) {
    crc ^= data[i];
    for (int b = 0; b < 8; ++b) crc = (crc & 1) ? (crc >> 1) ^ 0xA001 : crc >> 1;
  }
  return crc;
}

namespace {

Error Sys(const std::string& what) {
  return Error{ErrorCode::kIo, what + ": " + std::strerror(errno)};
}

// Expected length of a request frame from its first bytes (slave, fc, ...), or 0 if not yet
// known; -1 for a function code this controller does not implement (the whole burst is then
// taken as the frame, and libmodbus answers "illegal function").
int RequestLength(const std::vector<std::uint8_t>& b) {
  if (b.size() < 2) return 0;
  switch (b[1]) {
    case MODBUS_FC_READ_HOLDING_REGISTERS:
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
    case MODBUS_FC_READ_INPUT_REGISTERS:
      return 8;
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
      return b.size() < 7 ? 0 : 9 + b[6];
    default:
      return -1;
  }
}

}  // namespace

Result<std::unique_ptr<StageModbusRtuServer>> StageModbusRtuServer::Start(
    std::vector<SimulatedAxis*> axes, std::string link_path, FaultPlan* faults,
    const Clock* clock) {
  std::unique_ptr<StageModbusRtuServer> s(new StageModbusRtuServer());
  s->axes_ = std::move(axes);
  s->faults_ = faults;
  s->clock_ = clock;
  char name[256] = {};
  if (openpty(&s->master_, &s->slave_, name, nullptr, nullptr) != 0) return Sys("openpty");
  s->pty_path_ = name;
  // Raw bytes both ways (no echo, no line discipline); the client's libmodbus sets its own
  // termios on open as well. The server keeps the slave open so that a client closing it does
  // not hang up the master.
  termios tio{};
  tcgetattr(s->slave_, &tio);
  cfmakeraw(&tio);
  tcsetattr(s->slave_, TCSANOW, &tio);
  if (socketpair(AF_UNIX, SOCK_STREAM, 0, s->reply_) != 0) return Sys("socketpair");
  modbus_t* ctx = modbus_new_rtu(name, 115200, 'N', 8, 1);  // never connected: replies only
  if (!ctx) return Sys("modbus_new_rtu");
  s->ctx_ = ctx;
  modbus_set_socket(ctx, s->reply_[0]);
  s->map_ = modbus_mapping_new_start_address(0, 0, 0, 0, 0, stage_reg::kCount, 0, 0);
  if (!link_path.empty()) {
    struct stat st {};
    if (lstat(link_path.c_str(), &st) == 0) {
      if (!S_ISLNK(st.st_mode))
        return Error{ErrorCode::kInvalidArgument,
                     link_path + " exists and is not a symlink; not replacing it"};
      unlink(link_path.c_str());
    }
    if (symlink(name, link_path.c_str()) != 0) return Sys("symlink " + link_path);
    s->link_path_ = link_path;
  }
  s->thread_ = std::thread([p = s.get()] { p->Loop(); });
  return s;
}

StageModbusRtuServer::~StageModbusRtuServer() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (!link_path_.empty()) unlink(link_path_.c_str());
  if (map_) modbus_mapping_free(static_cast<modbus_mapping_t*>(map_));
  if (ctx_) modbus_free(static_cast<modbus_t*>(ctx_));
  for (int fd : {master_, slave_, reply_[0], reply_[1]})
    if (fd >= 0) close(fd);
}

void StageModbusRtuServer::Loop() {
  std::vector<std::uint8_t> frame;
  while (!stop_) {
    fd_set rd;
    FD_ZERO(&rd);
    FD_SET(master_, &rd);
    // Inside a frame, a silence of 20 ms ends it (far longer than 3.5 characters at any baud
    // rate, and a pty delivers a client's frame in one burst); between frames, 50 ms wakes the
    // loop to notice stop_.
    timeval tv{0, frame.empty() ? 50'000 : 20'000};
    const int n = select(master_ + 1, &rd, nullptr, nullptr, &tv);
    if (n < 0 && errno != EINTR) break;
    if (n <= 0) {
      if (!frame.empty()) {  // silence: a truncated or unknown frame ends here
        Answer(frame.data(), static_cast<int>(frame.size()));
        frame.clear();
      }
      continue;
    }
    std::uint8_t buf[512];
    const ssize_t got = read(master_, buf, sizeof buf);
    if (got <= 0) continue;  // EIO while no client has the slave open: wait
    frame.insert(frame.end(), buf, buf + got);
    // Complete frames are answered at once; bytes beyond one frame begin the next.
    for (int len = RequestLength(frame); len > 0 && static_cast<int>(frame.size()) >= len;
         len = RequestLength(frame)) {
      Answer(frame.data(), len);
      frame.erase(frame.begin(), frame.begin() + len);
    }
  }
}

void StageModbusRtuServer::Answer(const std::uint8_t* frame, int length) {
  if (length < 4) return;  // noise
  const std::uint16_t crc = ModbusCrc16(frame, static_cast<std::size_t>(length - 2));
  if (frame[length - 2] != (crc & 0xFF) || frame[length - 1] != (crc >> 8)) return;  // silent
  const int slave = frame[0];
  if (slave < 1 || slave > static_cast<int>(axes_.size())) return;  // someone else's frame
  SimulatedAxis& axis = *axes_[slave - 1];
  const double now = clock_ ? clock_->Now() : 0;
  if (MaybeFire(faults_, FaultKind::kModbusTimeout, axis.name(), now)) return;
  auto* ctx = static_cast<modbus_t*>(ctx_);
  modbus_set_slave(ctx, slave);
  const int sent = ReplyForAxis(ctx, static_cast<modbus_mapping_t*>(map_), axis, frame, length,
                                /*header=*/1);
  if (sent <= 0) return;
  std::vector<std::uint8_t> reply(static_cast<std::size_t>(sent));
  std::size_t have = 0;
  while (have < reply.size()) {  // libmodbus wrote it in one write(); read it back whole
    const ssize_t r = read(reply_[1], reply.data() + have, reply.size() - have);
    if (r <= 0) return;
    have += static_cast<std::size_t>(r);
  }
  if (MaybeFire(faults_, FaultKind::kModbusCrc, axis.name(), now)) reply.back() ^= 0x5A;
  ++requests_;
  if (const int baud = baud_; baud > 0) {  // the line's time for request, reply and their gaps
    const double chars = length + static_cast<double>(reply.size()) + 2 * 3.5;
    const double busy = chars * 11.0 / baud;
    line_busy_us_ += std::llround(busy * 1e6);
    std::this_thread::sleep_for(std::chrono::duration<double>(busy));
  }
  const std::uint8_t* p = reply.data();
  std::size_t left = reply.size();
  while (left > 0) {
    const ssize_t w = write(master_, p, left);
    if (w <= 0) return;
    p += w;
    left -= static_cast<std::size_t>(w);
  }
}

}  // namespace gonio::sim
