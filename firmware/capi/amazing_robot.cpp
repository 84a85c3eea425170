// The C API over the core. Host only: this is the one place that allocates.
#include "amazing_robot.h"

#include <new>

#include "battery.h"
#include "nmea.h"
#include "protocol.h"
#include "robot_app.h"

struct amz_robot {
  amz::RobotApp app;
};

namespace {

amz::RobotConfig to_core(const amz_robot_config& c) {
  amz::RobotConfig r;
  r.node = c.node;
  r.base_node = c.base_node;
  r.motion.max_velocity_mm_s = c.max_velocity_mm_s;
  r.motion.accel_mm_s2 = c.accel_mm_s2;
  r.motion.stop_decel_mm_s2 = c.stop_decel_mm_s2;
  r.motion.dead_man_ms = c.dead_man_ms;
  r.motion.reverse_dwell_ms = c.reverse_dwell_ms;
  r.motion.full_scale_mm_s = c.full_scale_mm_s;
  r.motion.duty_min = c.duty_min;
  r.motion.duty_max = c.duty_max;
  r.hard_max_velocity_mm_s = c.hard_max_velocity_mm_s;
  r.accel_min_mm_s2 = c.accel_min_mm_s2;
  r.accel_max_mm_s2 = c.accel_max_mm_s2;
  r.battery.vref_mv = c.battery_vref_mv;
  r.battery.divider_num = c.battery_divider_num;
  r.battery.divider_den = c.battery_divider_den;
  r.battery.adc_full_scale = c.battery_adc_full_scale;
  r.battery_median_window = c.battery_median_window;
  r.low_battery_10mv = c.low_battery_10mv;
  r.low_battery_hysteresis_10mv = c.low_battery_hysteresis_10mv;
  r.gps_stale_ms = c.gps_stale_ms;
  r.wheel_stale_ms = c.wheel_stale_ms;
  for (size_t i = 0; i <= amz::kBuildIdSize; ++i) {
    r.build_id[i] = i < amz::kBuildIdSize ? c.build_id[i] : 0;
  }
  return r;
}

amz::CommandFrame to_core(const amz_command& c) {
  amz::CommandFrame f = {c.to_node, c.from_node, c.seq, c.velocity_mm_s,
                         c.direction, c.flags, c.ttl_ms};
  return f;
}

amz::TelemetryFrame to_core(const amz_telemetry& t) {
  amz::TelemetryFrame f;
  f.to_node = t.to_node;
  f.from_node = t.from_node;
  f.seq = t.seq;
  f.echo_seq = t.echo_seq;
  f.robot_clock_ms = t.robot_clock_ms;
  f.velocity_mm_s = t.velocity_mm_s;
  f.direction = t.direction;
  f.battery_10mv = t.battery_10mv;
  f.lat_e7 = t.lat_e7;
  f.lon_e7 = t.lon_e7;
  f.fix_quality = t.fix_quality;
  f.satellites = t.satellites;
  f.status = t.status;
  f.rssi_dbm = t.rssi_dbm;
  return f;
}

amz::ConfigFrame to_core(const amz_config& c) {
  amz::ConfigFrame f = {c.to_node, c.from_node, c.seq, c.max_velocity_mm_s, c.accel_mm_s2};
  return f;
}

amz::ConfigAckFrame to_core(const amz_config_ack& a) {
  amz::ConfigAckFrame f = {a.to_node,           a.from_node,   a.seq,
                           a.max_velocity_mm_s, a.accel_mm_s2, a.hard_max_velocity_mm_s};
  return f;
}

amz::IdentifyFrame to_core(const amz_identify& q) {
  amz::IdentifyFrame f = {q.to_node, q.from_node, q.seq};
  return f;
}

amz::IdentityFrame to_core(const amz_identity& y) {
  amz::IdentityFrame f;
  f.to_node = y.to_node;
  f.from_node = y.from_node;
  f.seq = y.seq;
  for (size_t i = 0; i <= amz::kBuildIdSize; ++i) f.build_id[i] = y.build_id[i];
  f.hard_max_velocity_mm_s = y.hard_max_velocity_mm_s;
  f.max_velocity_mm_s = y.max_velocity_mm_s;
  f.accel_mm_s2 = y.accel_mm_s2;
  f.accel_min_mm_s2 = y.accel_min_mm_s2;
  f.accel_max_mm_s2 = y.accel_max_mm_s2;
  f.stop_decel_mm_s2 = y.stop_decel_mm_s2;
  f.dead_man_ms = y.dead_man_ms;
  f.reverse_dwell_ms = y.reverse_dwell_ms;
  f.full_scale_mm_s = y.full_scale_mm_s;
  f.low_battery_10mv = y.low_battery_10mv;
  f.gps_stale_ms = y.gps_stale_ms;
  f.battery_median_window = y.battery_median_window;
  return f;
}

int encoded(amz::FrameError e, size_t written) {
  return e == amz::FRAME_OK ? static_cast<int>(written) : -static_cast<int>(e);
}

}  // namespace

extern "C" {

uint32_t amz_abi_version(void) { return AMZ_ABI_VERSION; }

void amz_robot_default_config(amz_robot_config* out) {
  if (out == 0) return;
  const amz::RobotConfig r = amz::default_robot_config();
  out->node = r.node;
  out->base_node = r.base_node;
  out->max_velocity_mm_s = r.motion.max_velocity_mm_s;
  out->accel_mm_s2 = r.motion.accel_mm_s2;
  out->stop_decel_mm_s2 = r.motion.stop_decel_mm_s2;
  out->dead_man_ms = r.motion.dead_man_ms;
  out->reverse_dwell_ms = r.motion.reverse_dwell_ms;
  out->full_scale_mm_s = r.motion.full_scale_mm_s;
  out->duty_min = r.motion.duty_min;
  out->duty_max = r.motion.duty_max;
  out->hard_max_velocity_mm_s = r.hard_max_velocity_mm_s;
  out->accel_min_mm_s2 = r.accel_min_mm_s2;
  out->accel_max_mm_s2 = r.accel_max_mm_s2;
  out->battery_vref_mv = r.battery.vref_mv;
  out->battery_divider_num = r.battery.divider_num;
  out->battery_divider_den = r.battery.divider_den;
  out->battery_adc_full_scale = r.battery.adc_full_scale;
  out->battery_median_window = r.battery_median_window;
  out->low_battery_10mv = r.low_battery_10mv;
  out->low_battery_hysteresis_10mv = r.low_battery_hysteresis_10mv;
  out->gps_stale_ms = r.gps_stale_ms;
  out->wheel_stale_ms = r.wheel_stale_ms;
  for (size_t i = 0; i <= amz::kBuildIdSize; ++i) out->build_id[i] = r.build_id[i];
}

amz_robot* amz_robot_create(const amz_robot_config* config, uint32_t now_ms, int e_stop_latched,
                            int watchdog_reset) {
  if (config == 0) return 0;
  amz_robot* robot = new (std::nothrow) amz_robot;
  if (robot == 0) return 0;
  robot->app.init(to_core(*config), now_ms, e_stop_latched != 0, watchdog_reset != 0);
  return robot;
}

void amz_robot_destroy(amz_robot* robot) { delete robot; }

size_t amz_robot_handle_frame(amz_robot* robot, uint32_t now_ms, const uint8_t* frame, size_t len,
                              int8_t rssi_dbm, uint8_t* reply, size_t reply_cap) {
  if (robot == 0) return 0;
  return robot->app.handle_frame(now_ms, frame, len, rssi_dbm, reply, reply_cap);
}

void amz_robot_step(amz_robot* robot, uint32_t now_ms, amz_motion_output* out) {
  if (robot == 0) return;
  const amz::MotionOutput m = robot->app.step(now_ms);
  if (out == 0) return;
  out->duty = m.duty;
  out->direction = m.direction;
  out->drive_enabled = m.drive_enabled ? 1 : 0;
  out->status = robot->app.status(now_ms);
  out->velocity_mm_s = m.velocity_mm_s;
}

void amz_robot_add_battery_sample(amz_robot* robot, uint16_t adc_counts) {
  if (robot != 0) robot->app.add_battery_sample(adc_counts);
}

void amz_robot_feed_gps(amz_robot* robot, uint32_t now_ms, const char* data, size_t len) {
  if (robot == 0 || data == 0) return;
  for (size_t i = 0; i < len; ++i) robot->app.feed_gps(now_ms, data[i]);
}

void amz_robot_set_local_stop(amz_robot* robot, int open) {
  if (robot != 0) robot->app.set_local_stop(open != 0);
}

void amz_robot_set_measured_velocity(amz_robot* robot, uint32_t now_ms, uint16_t velocity_mm_s) {
  if (robot != 0) robot->app.set_measured_velocity(now_ms, velocity_mm_s);
}

int amz_robot_e_stop_latched(const amz_robot* robot) {
  return robot != 0 && robot->app.e_stop_latched() ? 1 : 0;
}

uint8_t amz_robot_status(const amz_robot* robot, uint32_t now_ms) {
  return robot == 0 ? 0 : robot->app.status(now_ms);
}

uint16_t amz_robot_battery_10mv(const amz_robot* robot) {
  return robot == 0 ? 0 : robot->app.battery_10mv();
}

int amz_encode_command(const amz_command* frame, uint8_t* out, size_t cap) {
  if (frame == 0) return -AMZ_ERR_BUFFER_TOO_SMALL;
  size_t written = 0;
  const amz::FrameError e = amz::encode_command(to_core(*frame), out, cap, &written);
  return encoded(e, written);
}

int amz_encode_telemetry(const amz_telemetry* frame, uint8_t* out, size_t cap) {
  if (frame == 0) return -AMZ_ERR_BUFFER_TOO_SMALL;
  size_t written = 0;
  const amz::FrameError e = amz::encode_telemetry(to_core(*frame), out, cap, &written);
  return encoded(e, written);
}

int amz_encode_config(const amz_config* frame, uint8_t* out, size_t cap) {
  if (frame == 0) return -AMZ_ERR_BUFFER_TOO_SMALL;
  size_t written = 0;
  const amz::FrameError e = amz::encode_config(to_core(*frame), out, cap, &written);
  return encoded(e, written);
}

int amz_encode_config_ack(const amz_config_ack* frame, uint8_t* out, size_t cap) {
  if (frame == 0) return -AMZ_ERR_BUFFER_TOO_SMALL;
  size_t written = 0;
  const amz::FrameError e = amz::encode_config_ack(to_core(*frame), out, cap, &written);
  return encoded(e, written);
}

int amz_encode_identify(const amz_identify* frame, uint8_t* out, size_t cap) {
  if (frame == 0) return -AMZ_ERR_BUFFER_TOO_SMALL;
  size_t written = 0;
  const amz::FrameError e = amz::encode_identify(to_core(*frame), out, cap, &written);
  return encoded(e, written);
}

int amz_encode_identity(const amz_identity* frame, uint8_t* out, size_t cap) {
  if (frame == 0) return -AMZ_ERR_BUFFER_TOO_SMALL;
  size_t written = 0;
  const amz::FrameError e = amz::encode_identity(to_core(*frame), out, cap, &written);
  return encoded(e, written);
}

int amz_decode_frame(const uint8_t* data, size_t len, amz_frame* out) {
  amz::Frame f;
  const amz::FrameError e = amz::decode_frame(data, len, &f);
  if (e != amz::FRAME_OK || out == 0) return e;
  out->type = f.type;
  if (f.type == amz::FRAME_COMMAND) {
    const amz::CommandFrame& c = f.command;
    amz_command r = {c.to_node, c.from_node, c.seq, c.velocity_mm_s, c.direction, c.flags,
                     c.ttl_ms};
    out->command = r;
  } else if (f.type == amz::FRAME_TELEMETRY) {
    const amz::TelemetryFrame& t = f.telemetry;
    amz_telemetry& r = out->telemetry;
    r.to_node = t.to_node;
    r.from_node = t.from_node;
    r.seq = t.seq;
    r.echo_seq = t.echo_seq;
    r.robot_clock_ms = t.robot_clock_ms;
    r.velocity_mm_s = t.velocity_mm_s;
    r.direction = t.direction;
    r.battery_10mv = t.battery_10mv;
    r.lat_e7 = t.lat_e7;
    r.lon_e7 = t.lon_e7;
    r.fix_quality = t.fix_quality;
    r.satellites = t.satellites;
    r.status = t.status;
    r.rssi_dbm = t.rssi_dbm;
  } else if (f.type == amz::FRAME_IDENTIFY) {
    amz_identify r = {f.identify.to_node, f.identify.from_node, f.identify.seq};
    out->identify = r;
  } else if (f.type == amz::FRAME_IDENTITY) {
    const amz::IdentityFrame& y = f.identity;
    amz_identity& r = out->identity;
    r.to_node = y.to_node;
    r.from_node = y.from_node;
    r.seq = y.seq;
    for (size_t i = 0; i <= amz::kBuildIdSize; ++i) r.build_id[i] = y.build_id[i];
    r.hard_max_velocity_mm_s = y.hard_max_velocity_mm_s;
    r.max_velocity_mm_s = y.max_velocity_mm_s;
    r.accel_mm_s2 = y.accel_mm_s2;
    r.accel_min_mm_s2 = y.accel_min_mm_s2;
    r.accel_max_mm_s2 = y.accel_max_mm_s2;
    r.stop_decel_mm_s2 = y.stop_decel_mm_s2;
    r.dead_man_ms = y.dead_man_ms;
    r.reverse_dwell_ms = y.reverse_dwell_ms;
    r.full_scale_mm_s = y.full_scale_mm_s;
    r.low_battery_10mv = y.low_battery_10mv;
    r.gps_stale_ms = y.gps_stale_ms;
    r.battery_median_window = y.battery_median_window;
  } else if (f.type == amz::FRAME_CONFIG_ACK) {
    const amz::ConfigAckFrame& a = f.config_ack;
    amz_config_ack r = {a.to_node,           a.from_node,   a.seq,
                        a.max_velocity_mm_s, a.accel_mm_s2, a.hard_max_velocity_mm_s};
    out->config_ack = r;
  } else {
    const amz::ConfigFrame& c = f.config;
    amz_config r = {c.to_node, c.from_node, c.seq, c.max_velocity_mm_s, c.accel_mm_s2};
    out->config = r;
  }
  return AMZ_OK;
}

const char* amz_frame_error_name(int kind) {
  return kind < 0 || kind > 255 ? "unknown" : amz::frame_error_name(static_cast<uint8_t>(kind));
}

int amz_parse_gga(const char* sentence, size_t len, amz_gga_fix* out) {
  amz::GgaFix fix;
  const amz::NmeaResult r = amz::parse_gga(sentence, len, &fix);
  if (r == amz::NMEA_OK && out != 0) {
    out->utc_ms_of_day = fix.utc_ms_of_day;
    out->lat_e7 = fix.lat_e7;
    out->lon_e7 = fix.lon_e7;
    out->quality = fix.quality;
    out->satellites = fix.satellites;
    out->has_position = fix.has_position ? 1 : 0;
  }
  return r;
}

uint16_t amz_battery_counts_to_10mv(uint16_t counts, uint16_t vref_mv, uint16_t divider_num,
                                    uint16_t divider_den, uint16_t adc_full_scale) {
  amz::BatteryConfig c;
  c.vref_mv = vref_mv;
  c.divider_num = divider_num;
  c.divider_den = divider_den;
  c.adc_full_scale = adc_full_scale;
  return amz::battery_counts_to_10mv(counts, c);
}

}  // extern "C"
