#include "sim/stage/modbus_tcp_server.h"

#include <arpa/inet.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <string>

#include "sim/stage/modbus_reply.h"

namespace gonio::sim {

Result<std::unique_ptr<StageModbusTcpServer>> StageModbusTcpServer::Start(
    std::vector<SimulatedAxis*> axes, int port, FaultPlan* faults, const Clock* clock) {
  std::unique_ptr<StageModbusTcpServer> s(new StageModbusTcpServer());
  s->axes_ = std::move(axes);
  s->faults_ = faults;
  s->clock_ = clock;
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", port);  // loopback only, never all interfaces
  if (!ctx) return Error{ErrorCode::kIo, std::string("modbus_new_tcp: ") + modbus_strerror(errno)};
  s->ctx_ = ctx;
  s->listen_fd_ = modbus_tcp_listen(ctx, 4);
  if (s->listen_fd_ < 0) {
    return Error{ErrorCode::kIo, "cannot listen on 127.0.0.1:" + std::to_string(port) + ": " +
                                     modbus_strerror(errno)};
  }
  sockaddr_in addr{};
  socklen_t len = sizeof addr;
  if (getsockname(s->listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0)
    return Error{ErrorCode::kIo, std::string("getsockname: ") + std::strerror(errno)};
  s->port_ = ntohs(addr.sin_port);
  s->thread_ = std::thread([p = s.get()] { p->Loop(); });
  return s;
}

StageModbusTcpServer::~StageModbusTcpServer() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) close(listen_fd_);
  if (ctx_) modbus_free(static_cast<modbus_t*>(ctx_));
}

void StageModbusTcpServer::Loop() {
  auto* ctx = static_cast<modbus_t*>(ctx_);
  modbus_mapping_t* map = modbus_mapping_new_start_address(0, 0, 0, 0, 0, stage_reg::kCount, 0, 0);
  const int header = modbus_get_header_length(ctx);  // 7 for TCP: ..., unit id
  std::vector<int> clients;
  std::uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
  while (!stop_) {
    fd_set rd;
    FD_ZERO(&rd);
    FD_SET(listen_fd_, &rd);
    int max_fd = listen_fd_;
    for (int fd : clients) FD_SET(fd, &rd), max_fd = std::max(max_fd, fd);
    timeval tv{0, 50'000};  // wake up to notice stop_
    if (select(max_fd + 1, &rd, nullptr, nullptr, &tv) <= 0) continue;
    if (FD_ISSET(listen_fd_, &rd)) {
      const int fd = accept(listen_fd_, nullptr, nullptr);
      if (fd >= 0) clients.push_back(fd);
    }
    for (auto it = clients.begin(); it != clients.end();) {
      if (!FD_ISSET(*it, &rd)) {
        ++it;
        continue;
      }
      modbus_set_socket(ctx, *it);
      const int rc = modbus_receive(ctx, query);
      if (rc == -1) {  // closed or broken: forget the client
        close(*it);
        it = clients.erase(it);
        continue;
      }
      if (rc > 0) {
        const int unit = query[header - 1];
        if (unit < 1 || unit > static_cast<int>(axes_.size())) {
          modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_GATEWAY_TARGET);
        } else {
          SimulatedAxis* axis = axes_[unit - 1];
          const double now = clock_ ? clock_->Now() : 0;
          if (MaybeFire(faults_, FaultKind::kModbusDrop, axis->name(), now)) {
            close(*it);  // the fault plan: the controller drops the connection unanswered
            it = clients.erase(it);
            continue;
          }
          // The fault plan: no reply at all; the client's response timeout expires.
          if (!MaybeFire(faults_, FaultKind::kModbusTimeout, axis->name(), now))
            ReplyForAxis(ctx, map, *axis, query, rc, header);
        }
      }
      ++it;
    }
  }
  for (int fd : clients) close(fd);
  modbus_mapping_free(map);
}

}  // namespace gonio::sim
