#include "config/instrument_config.h"

#include <cmath>

#include "config/toml_reader.h"

namespace gonio::config {

namespace {

Status Bit(Reader& r, const toml::table& t, const char* key, std::uint32_t* out) {
  std::int64_t bit = -1;
  if (Status s = r.Integer(t, key, &bit, 0, 31); !s.ok()) return s;
  if (bit >= 0) *out = 1u << bit;
  return OkStatus();
}

// [camera.features]: the vendor's names for cooling, the shutter and the exposure status.
Status ReadFeatures(Reader& r, const toml::table& k, devices::VendorFeatures& f) {
  GONIO_TRY(r.Keys(
      k, "camera.features",
      {"temperature_selector", "temperature_selector_value", "temperature", "control_mode",
       "control_on", "control_off", "setpoint", "setpoint_activate", "shutter", "shutter_open",
       "shutter_closed", "status_selector", "status_selector_value", "status"}));
  GONIO_TRY(r.String(k, "temperature_selector", &f.temperature_selector));
  GONIO_TRY(r.String(k, "temperature_selector_value", &f.temperature_selector_value));
  GONIO_TRY(r.String(k, "temperature", &f.temperature));  // empty: the camera has no sensor
  GONIO_TRY(r.String(k, "control_mode", &f.control_mode));
  GONIO_TRY(r.String(k, "control_on", &f.control_on));
  GONIO_TRY(r.String(k, "control_off", &f.control_off));
  GONIO_TRY(r.String(k, "setpoint", &f.setpoint));
  GONIO_TRY(r.String(k, "setpoint_activate", &f.setpoint_activate));
  GONIO_TRY(r.String(k, "shutter", &f.shutter));
  GONIO_TRY(r.String(k, "shutter_open", &f.shutter_open));
  GONIO_TRY(r.String(k, "shutter_closed", &f.shutter_closed));
  GONIO_TRY(r.String(k, "status_selector", &f.status_selector));
  GONIO_TRY(r.String(k, "status_selector_value", &f.status_selector_value));
  GONIO_TRY(r.String(k, "status", &f.status));
  return OkStatus();
}

// [camera]: address, format, region, buffers and retries, and its [camera.features].
Status ReadCamera(Reader& r, const toml::table& t, InstrumentConfig& c) {
  GONIO_TRY(r.Keys(t, "camera",
                   {"enabled", "address", "pixel_format", "gain_db", "black_level", "binning",
                    "roi", "buffers", "frame_timeout_s", "latch_timeout_s", "retries",
                    "linear_limit_adu", "status_poll_s", "heartbeat_timeout_s", "features"}));
  devices::CameraSettings& s = c.camera;
  GONIO_TRY(r.Bool(t, "enabled", &c.camera_enabled));
  GONIO_TRY(r.Ipv4(t, "address", &s.address));
  GONIO_TRY(r.String(t, "pixel_format", &s.pixel_format, {"Mono12", "Mono16"}));
  GONIO_TRY(r.Number(t, "gain_db", &s.gain_db, 0, 48));
  GONIO_TRY(r.Integer(t, "black_level", &s.black_level, -1, 65535));
  GONIO_TRY(r.Integer(t, "binning", &s.binning, 1, 16));
  GONIO_TRY(r.Integer(t, "buffers", &s.buffers, 2, 64));
  GONIO_TRY(r.Integer(t, "retries", &s.retries, 0, 10));
  GONIO_TRY(r.Number(t, "frame_timeout_s", &s.frame_timeout_s, 0.01, 600));
  GONIO_TRY(r.Number(t, "latch_timeout_s", &s.latch_timeout_s, 0.01, 600));
  GONIO_TRY(r.Number(t, "linear_limit_adu", &s.linear_limit_adu, 100, 65535));
  GONIO_TRY(r.Number(t, "status_poll_s", &s.status_poll_s, 1e-4, 1));
  GONIO_TRY(r.Number(t, "heartbeat_timeout_s", &s.heartbeat_timeout_s, 0.5, 600));
  if (const toml::node* n = t.get("roi")) {
    const toml::array* a = n->as_array();
    if (a == nullptr || a->size() != 4 || !a->is_homogeneous<std::int64_t>())
      return r.Fail(n, "'roi' must be [x, y, width, height] in integers");
    s.roi_x = static_cast<int>(*(*a)[0].value<std::int64_t>());
    s.roi_y = static_cast<int>(*(*a)[1].value<std::int64_t>());
    s.roi_width = static_cast<int>(*(*a)[2].value<std::int64_t>());
    s.roi_height = static_cast<int>(*(*a)[3].value<std::int64_t>());
    if (s.roi_x < 0 || s.roi_y < 0 || s.roi_width < 0 || s.roi_height < 0)
      return r.Fail(n, "'roi' values must be >= 0");
  }
  if (const toml::table* k = t["features"].as_table()) GONIO_TRY(ReadFeatures(r, *k, s.features));
  return OkStatus();
}

// [stages.registers]: where the controller keeps what the driver uses.
Status ReadRegisters(Reader& r, const toml::table& g, devices::StageRegisterProfile& p) {
  GONIO_TRY(
      r.Keys(g, "stages.registers",
             {"direct_data", "operation_absolute", "current", "input_command", "output_status",
              "present_alarm", "command_position", "feedback_position", "alarm_reset",
              "in_home_bit", "in_stop_bit", "out_home_end_bit", "out_ready_bit", "out_alarm_bit",
              "out_move_bit", "out_in_pos_bit", "inputs_latched", "ready_timeout_s"}));
  GONIO_TRY(r.Integer(g, "direct_data", &p.direct_data, 0, 0xFFFF));
  GONIO_TRY(r.Integer(g, "input_command", &p.input_command, 0, 0xFFFF));
  GONIO_TRY(r.Integer(g, "output_status", &p.output_status, 0, 0xFFFF));
  GONIO_TRY(r.Integer(g, "present_alarm", &p.present_alarm, 0, 0xFFFF));
  GONIO_TRY(r.Integer(g, "command_position", &p.command_position, 0, 0xFFFF));
  GONIO_TRY(r.Integer(g, "feedback_position", &p.feedback_position, 0, 0xFFFF));
  GONIO_TRY(r.Bool(g, "inputs_latched", &p.inputs_latched));
  GONIO_TRY(r.Number(g, "ready_timeout_s", &p.ready_timeout_s, 0.01, 60));
  GONIO_TRY(r.Integer(g, "alarm_reset", &p.alarm_reset, 0, 0xFFFF));
  GONIO_TRY(r.Integer(g, "operation_absolute", &p.operation_absolute, 0, 0xFFFF));
  GONIO_TRY(r.Integer(g, "current", &p.current, 0, 1000));
  GONIO_TRY(Bit(r, g, "in_home_bit", &p.in_home));
  GONIO_TRY(Bit(r, g, "in_stop_bit", &p.in_stop));
  GONIO_TRY(Bit(r, g, "out_home_end_bit", &p.out_home_end));
  GONIO_TRY(Bit(r, g, "out_ready_bit", &p.out_ready));
  GONIO_TRY(Bit(r, g, "out_alarm_bit", &p.out_alarm));
  GONIO_TRY(Bit(r, g, "out_move_bit", &p.out_move));
  GONIO_TRY(Bit(r, g, "out_in_pos_bit", &p.out_in_pos));
  return OkStatus();
}

// [[stages.axis]]: each axis's unit id, gearing, travel limits and motion.
Status ReadAxes(Reader& r, const toml::node& n, std::vector<devices::AxisSettings>& axes) {
  const toml::array* list = n.as_array();
  if (list == nullptr || list->empty()) return r.Fail(&n, "[[stages.axis]] must list axes");
  std::set<std::string> names;
  std::set<std::int64_t> ids;
  for (const toml::node& item : *list) {
    const toml::table* a = item.as_table();
    if (a == nullptr) return r.Fail(&item, "each [[stages.axis]] must be a table");
    GONIO_TRY(r.Keys(*a, "stages.axis",
                     {"name", "slave_id", "steps_per_degree", "degrees_at_zero", "min_deg",
                      "max_deg", "backlash_overshoot_deg", "speed_deg_s", "acceleration_deg_s2",
                      "tolerance_deg", "move_timeout_s", "home_timeout_s"}));
    devices::AxisSettings ax;
    if (a->get("name") == nullptr) return r.Fail(&item, "axis without 'name'");
    GONIO_TRY(r.String(*a, "name", &ax.name, {"arm", "azimuth", "beam_block", "sample"}));
    if (!names.insert(ax.name).second)
      return r.Fail(a->get("name"), "axis '" + ax.name + "' configured twice");
    std::int64_t id = static_cast<std::int64_t>(names.size());
    GONIO_TRY(r.Integer(*a, "slave_id", &id, 1, 247));
    if (!ids.insert(id).second)
      return r.Fail(a->get("slave_id") ? a->get("slave_id") : &item,
                    "slave_id " + std::to_string(id) + " given to two axes");
    ax.slave_id = static_cast<int>(id);
    GONIO_TRY(r.Number(*a, "steps_per_degree", &ax.steps_per_degree, 1e-3, 1e7));
    GONIO_TRY(r.Number(*a, "degrees_at_zero", &ax.degrees_at_zero, -360, 360));
    GONIO_TRY(r.Number(*a, "min_deg", &ax.min_deg, -720, 720));
    GONIO_TRY(r.Number(*a, "max_deg", &ax.max_deg, -720, 720));
    if (!(ax.min_deg < ax.max_deg)) return r.Fail(a, "min_deg must be below max_deg");
    GONIO_TRY(r.Number(*a, "backlash_overshoot_deg", &ax.backlash_overshoot_deg, 0, 10));
    GONIO_TRY(r.Number(*a, "speed_deg_s", &ax.speed_deg_s, 1e-3, 1000));
    GONIO_TRY(r.Number(*a, "acceleration_deg_s2", &ax.acceleration_deg_s2, 1e-3, 1e5));
    GONIO_TRY(r.Number(*a, "tolerance_deg", &ax.tolerance_deg, 1e-6, 10));
    GONIO_TRY(r.Number(*a, "move_timeout_s", &ax.move_timeout_s, 0.1, 3600));
    GONIO_TRY(r.Number(*a, "home_timeout_s", &ax.home_timeout_s, 0.1, 3600));
    axes.push_back(ax);
  }
  return OkStatus();
}

// [stages]: the Modbus link, then its registers and axes.
Status ReadStages(Reader& r, const toml::table& t, InstrumentConfig& c) {
  GONIO_TRY(r.Keys(t, "stages",
                   {"link", "host", "port", "device", "baud", "parity", "data_bits", "stop_bits",
                    "response_timeout_s", "retries", "poll_interval_s", "registers", "axis"}));
  devices::ModbusLink& l = c.stage_link;
  GONIO_TRY(r.Choice(t, "link", &l.kind, devices::kModbusTransportNames));
  GONIO_TRY(r.Ipv4(t, "host", &l.host));
  GONIO_TRY(r.Integer(t, "port", &l.port, 1, 65535));
  GONIO_TRY(r.String(t, "device", &l.device));
  if (l.kind == devices::ModbusTransport::kRtu && l.device.empty())
    return r.Fail(t.get("link"), "an RTU link needs 'device' (the serial port)");
  GONIO_TRY(r.Integer(t, "baud", &l.baud, 1200, 4'000'000));
  std::string parity = "even";
  GONIO_TRY(r.String(t, "parity", &parity, {"even", "none", "odd"}));
  l.parity = parity == "even" ? 'E' : parity == "odd" ? 'O' : 'N';
  GONIO_TRY(r.Integer(t, "data_bits", &l.data_bits, 7, 8));
  GONIO_TRY(r.Integer(t, "stop_bits", &l.stop_bits, 1, 2));
  GONIO_TRY(r.Number(t, "response_timeout_s", &l.response_timeout_s, 0.01, 30));
  GONIO_TRY(r.Integer(t, "retries", &l.retries, 0, 20));
  GONIO_TRY(r.Number(t, "poll_interval_s", &l.poll_interval_s, 0, 1));
  if (const toml::table* g = t["registers"].as_table())
    GONIO_TRY(ReadRegisters(r, *g, c.registers));
  if (const toml::node* n = t.get("axis")) GONIO_TRY(ReadAxes(r, *n, c.axes));
  return OkStatus();
}

// [monitor]: the source monitor's transport and settings.
Status ReadMonitor(Reader& r, const toml::table& t, MonitorConfig& m) {
  m.enabled = true;
  GONIO_TRY(r.Keys(t, "monitor",
                   {"enabled", "transport", "vendor_id", "product_id", "serial", "host", "port",
                    "wavelength_nm", "averaging", "timeout_ms"}));
  GONIO_TRY(r.Bool(t, "enabled", &m.enabled));
  GONIO_TRY(r.Choice(t, "transport", &m.transport, kMonitorTransportNames));
  GONIO_TRY(r.Integer(t, "vendor_id", &m.usb.vendor_id, 0, 0xFFFF));
  GONIO_TRY(r.Integer(t, "product_id", &m.usb.product_id, 0, 0xFFFF));
  GONIO_TRY(r.String(t, "serial", &m.usb.serial));
  GONIO_TRY(r.Ipv4(t, "host", &m.host));
  GONIO_TRY(r.Integer(t, "port", &m.port, 1, 65535));
  GONIO_TRY(r.Number(t, "wavelength_nm", &m.wavelength_nm, 200, 2000));
  GONIO_TRY(r.Integer(t, "averaging", &m.averaging, 1, 100000));
  GONIO_TRY(r.Integer(t, "timeout_ms", &m.timeout_ms, 10, 60000));
  return OkStatus();
}

// [beam_block]: the flag's two positions, within its axis's travel limits.
Status ReadBeamBlock(Reader& r, const toml::table& t, const InstrumentConfig& c,
                     devices::BeamBlockSettings& b) {
  GONIO_TRY(r.Keys(t, "beam_block", {"open_deg", "blocked_deg"}));
  const devices::AxisSettings* axis = nullptr;
  for (const auto& a : c.axes)
    if (a.name == "beam_block") axis = &a;
  if (axis == nullptr)
    return r.Fail(&t, "[beam_block] needs an axis named \"beam_block\" in [[stages.axis]]");
  for (const char* key : {"open_deg", "blocked_deg"})
    if (t.get(key) == nullptr) return r.Fail(&t, std::string("[beam_block] needs '") + key + "'");
  GONIO_TRY(r.Number(t, "open_deg", &b.open_deg, axis->min_deg, axis->max_deg));
  GONIO_TRY(r.Number(t, "blocked_deg", &b.blocked_deg, axis->min_deg, axis->max_deg));
  if (std::abs(b.open_deg - b.blocked_deg) < 1)
    return r.Fail(t.get("blocked_deg"), "blocked_deg must be at least 1 deg from open_deg");
  return OkStatus();
}

// [bench]: the optics' geometry (docs/measurement.md).
Status ReadBench(Reader& r, const toml::table& t, optics::BenchOptics& b) {
  GONIO_TRY(r.Keys(t, "bench",
                   {"source_distance_mm", "camera_distance_mm", "sphere_radius_mm", "lens_eta",
                    "centred_thickness_mm", "plate_half_width_mm", "mm_per_pixel", "sensor_width",
                    "sensor_height", "source_sr", "receiver_sr", "angle_sigma_deg",
                    "thickness_sigma_mm", "rectangle_sigma_px", "axis_x_px", "axis_y_px"}));
  GONIO_TRY(r.Number(t, "source_distance_mm", &b.source_distance_mm, 1, 1e5));
  GONIO_TRY(r.Number(t, "camera_distance_mm", &b.camera_distance_mm, 1, 1e5));
  GONIO_TRY(r.Number(t, "sphere_radius_mm", &b.sphere_radius_mm, 1, 1e4));
  GONIO_TRY(r.Number(t, "lens_eta", &b.lens_eta, 1.0001, 2.9999));
  GONIO_TRY(r.Number(t, "centred_thickness_mm", &b.centred_thickness_mm, 0.01, 1000));
  GONIO_TRY(r.Number(t, "plate_half_width_mm", &b.plate_half_width_mm, 0.01, 1e4));
  GONIO_TRY(r.Number(t, "mm_per_pixel", &b.mm_per_pixel, 1e-6, 100));
  GONIO_TRY(r.Integer(t, "sensor_width", &b.sensor_width, 1, 100000));
  GONIO_TRY(r.Integer(t, "sensor_height", &b.sensor_height, 1, 100000));
  GONIO_TRY(r.Number(t, "source_sr", &b.source_sr, 0, 0.5));
  GONIO_TRY(r.Number(t, "receiver_sr", &b.receiver_sr, 0, 0.5));
  GONIO_TRY(r.Number(t, "angle_sigma_deg", &b.angle_sigma_deg, 0, 10));
  GONIO_TRY(r.Number(t, "thickness_sigma_mm", &b.thickness_sigma_mm, 0, 10));
  GONIO_TRY(r.Number(t, "rectangle_sigma_px", &b.rectangle_sigma_px, 0, 100));
  GONIO_TRY(r.Number(t, "axis_x_px", &b.axis_x_px, -b.sensor_width, b.sensor_width));
  GONIO_TRY(r.Number(t, "axis_y_px", &b.axis_y_px, -b.sensor_height, b.sensor_height));
  if (Status s = b.Validate(); !s.ok()) return r.Fail(&t, s.error().message);
  return OkStatus();
}

// [throughput]: scale and adu_per_value are needed (without them nothing is priced); the noise
// is all four terms or none.
Status ReadThroughput(Reader& r, const toml::table& t, ThroughputConfig& c) {
  GONIO_TRY(r.Keys(t, "throughput",
                   {"scale", "floor", "adu_per_value", "dark_adu", "noise_shot", "noise_read",
                    "noise_lamp", "noise_dark", "from_run"}));
  for (const char* key : {"scale", "adu_per_value"})
    if (t.get(key) == nullptr) return r.Fail(&t, std::string("[throughput] needs '") + key + "'");
  GONIO_TRY(r.Number(t, "scale", &c.scale, 1e-12, 1e15));
  GONIO_TRY(r.Number(t, "floor", &c.floor, 0, 1e15));
  GONIO_TRY(r.Number(t, "adu_per_value", &c.adu_per_value, 1e-12, 1e15));
  GONIO_TRY(r.Number(t, "dark_adu", &c.dark_adu, 0, 1e9));
  GONIO_TRY(r.Number(t, "noise_shot", &c.noise_shot, 0, 1e15));
  GONIO_TRY(r.Number(t, "noise_read", &c.noise_read, 0, 1e15));
  GONIO_TRY(r.Number(t, "noise_lamp", &c.noise_lamp, 0, 1));
  GONIO_TRY(r.Number(t, "noise_dark", &c.noise_dark, 0, 1e15));
  GONIO_TRY(r.Integer(t, "from_run", &c.from_run, 0, 1000000000));
  int noise_terms = 0;
  for (const char* key : {"noise_shot", "noise_read", "noise_lamp", "noise_dark"})
    noise_terms += t.get(key) != nullptr ? 1 : 0;
  if (noise_terms != 0 && noise_terms != 4)
    return r.Fail(&t,
                  "[throughput] gives the noise as all four of noise_shot, noise_read, "
                  "noise_lamp, noise_dark or none of them");
  return OkStatus();
}

}  // namespace

Result<InstrumentConfig> LoadInstrumentConfig(const std::string& path) {
  auto parsed = ParseTomlFile(path);
  if (!parsed.ok()) return parsed.error();
  const toml::table& root = *parsed;
  Reader r(path);
  InstrumentConfig c;
  GONIO_TRY(r.Keys(root, "top level",
                   {"camera", "stages", "monitor", "beam_block", "bench", "throughput"}));
  if (const toml::table* t = root["camera"].as_table()) GONIO_TRY(ReadCamera(r, *t, c));
  if (const toml::table* t = root["stages"].as_table()) GONIO_TRY(ReadStages(r, *t, c));
  if (c.axes.empty()) return r.Fail(nullptr, "no [[stages.axis]]: the instrument needs its axes");
  if (const toml::table* t = root["monitor"].as_table()) GONIO_TRY(ReadMonitor(r, *t, c.monitor));
  if (const toml::table* t = root["beam_block"].as_table()) {
    c.beam_block.emplace();
    GONIO_TRY(ReadBeamBlock(r, *t, c, *c.beam_block));
  } else if (root.get("beam_block") != nullptr) {
    return r.Fail(root.get("beam_block"), "[beam_block] must be a table");
  } else {
    for (const auto& a : c.axes)
      if (a.name == "beam_block")
        return r.Fail(nullptr,
                      "the axis \"beam_block\" needs a [beam_block] table (open_deg, blocked_deg)");
  }
  if (const toml::table* t = root["bench"].as_table()) {
    c.bench.emplace();
    GONIO_TRY(ReadBench(r, *t, *c.bench));
  }
  if (const toml::table* t = root["throughput"].as_table()) {
    c.throughput.emplace();
    GONIO_TRY(ReadThroughput(r, *t, *c.throughput));
  } else if (root.get("throughput") != nullptr) {
    return r.Fail(root.get("throughput"), "[throughput] must be a table");
  }
  return c;
}

}  // namespace gonio::config
