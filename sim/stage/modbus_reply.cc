#include "sim/stage/modbus_reply.h"

#include <algorithm>

namespace gonio::sim {

int ReplyForAxis(modbus_t* ctx, modbus_mapping_t* map, SimulatedAxis& axis,
                 const std::uint8_t* query, int length, int header) {
  std::uint16_t regs[stage_reg::kCount];
  axis.Snapshot(regs);
  std::copy(regs, regs + stage_reg::kCount, map->tab_registers);
  const int replied = modbus_reply(ctx, query, length, map);
  const int fc = query[header];
  const int address = (query[header + 1] << 8) | query[header + 2];
  // A successful write: the axis acts on the registers written.
  if (replied > 0 && address < stage_reg::kCount) {
    if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER) {
      axis.Write(static_cast<std::uint16_t>(address), &map->tab_registers[address], 1);
    } else if (fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS) {
      const int count = (query[header + 3] << 8) | query[header + 4];
      if (address + count <= stage_reg::kCount)
        axis.Write(static_cast<std::uint16_t>(address), &map->tab_registers[address], count);
    }
  }
  return replied;
}

}  // namespace gonio::sim
