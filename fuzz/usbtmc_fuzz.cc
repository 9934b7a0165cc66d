// USBTMC framing from the device's side: whatever bytes a meter's bulk-in transfers and class
// requests return, a query ends in a response or an error, never a crash or a hang. The input is
// split into transfers at each 0xFF 0xFE pair; class requests answer from the same stream.
#include <algorithm>
#include <cstring>
#include <vector>

#include "devices/usbtmc.h"
#include "devices/usbtmc_transport.h"

namespace {

class FuzzTransport final : public gonio::devices::UsbTmcTransport {
 public:
  FuzzTransport(const std::uint8_t* data, std::size_t size) {
    std::vector<std::uint8_t> cur;
    for (std::size_t i = 0; i < size; ++i) {
      if (i + 1 < size && data[i] == 0xFF && data[i + 1] == 0xFE) {
        chunks_.push_back(cur);
        cur.clear();
        ++i;
      } else {
        cur.push_back(data[i]);
      }
    }
    chunks_.push_back(cur);
  }
  gonio::Status BulkOut(const std::uint8_t*, std::size_t, int) override {
    return gonio::OkStatus();
  }
  gonio::Result<std::size_t> BulkIn(std::uint8_t* out, std::size_t capacity, int) override {
    if (next_ >= chunks_.size()) return gonio::Error{gonio::ErrorCode::kTimeout, "no more"};
    const auto& c = chunks_[next_++];
    const std::size_t n = std::min(capacity, c.size());
    if (n > 0) std::memcpy(out, c.data(), n);
    return n;
  }
  gonio::Result<std::vector<std::uint8_t>> ClassRequest(std::uint8_t, std::uint16_t,
                                                        std::uint16_t length, int) override {
    if (next_ >= chunks_.size()) return gonio::Error{gonio::ErrorCode::kTimeout, "no more"};
    auto c = chunks_[next_++];
    if (c.size() > length) c.resize(length);
    return c;
  }
  gonio::Status ClearHalt(gonio::devices::UsbTmcEndpoint) override { return gonio::OkStatus(); }
  gonio::Status Reopen() override { return gonio::OkStatus(); }

 private:
  std::vector<std::vector<std::uint8_t>> chunks_;
  std::size_t next_ = 0;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzTransport t(data, size);
  gonio::devices::UsbTmc tmc(t, 10);
  (void)tmc.Query("MEAS:POW?");
  (void)tmc.Query("SYST:ERR?");
  (void)tmc.Clear();
  return 0;
}
