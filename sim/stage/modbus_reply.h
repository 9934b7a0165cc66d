// What both stage servers (TCP and RTU) do with one request that reached an axis: answer it with
// libmodbus's reply builder over the axis's registers, then hand any written registers to the
// axis so that it acts on them. Internal to sim/stage (it names libmodbus types).
#pragma once

#include <modbus/modbus.h>

#include <cstdint>

#include "sim/stage/axis.h"

namespace gonio::sim {

// `query` is the whole ADU as libmodbus receives it, `header` the backend's header length (7 for
// TCP, 1 for RTU). `map` is scratch space of stage_reg::kCount holding registers. Returns what
// modbus_reply returns (bytes sent, or -1).
int ReplyForAxis(modbus_t* ctx, modbus_mapping_t* map, SimulatedAxis& axis,
                 const std::uint8_t* query, int length, int header);

}  // namespace gonio::sim
