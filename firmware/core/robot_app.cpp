#include "robot_app.h"

#include "robot_config.h"

namespace amz {

// A longer identifier would be cut on the wire: refuse to build instead.
static_assert(sizeof(AMZ_BUILD_ID) <= kBuildIdSize + 1, "AMZ_BUILD_ID: at most 16 characters");

RobotConfig default_robot_config() {
  RobotConfig c;
  const char* id = AMZ_BUILD_ID;
  for (uint8_t i = 0; i <= kBuildIdSize; ++i) c.build_id[i] = i < sizeof(AMZ_BUILD_ID) ? id[i] : 0;
  c.node = AMZ_ROBOT_NODE;
  c.base_node = AMZ_BASE_NODE;
  c.motion.max_velocity_mm_s = AMZ_MAX_VELOCITY_MM_S;
  c.motion.accel_mm_s2 = AMZ_ACCEL_MM_S2;
  c.motion.stop_decel_mm_s2 = AMZ_STOP_DECEL_MM_S2;
  c.motion.dead_man_ms = AMZ_DEAD_MAN_MS;
  c.motion.reverse_dwell_ms = AMZ_REVERSE_DWELL_MS;
  c.motion.full_scale_mm_s = AMZ_FULL_SCALE_MM_S;
  c.motion.duty_min = AMZ_DUTY_MIN;
  c.motion.duty_max = AMZ_DUTY_MAX;
  c.hard_max_velocity_mm_s = AMZ_HARD_MAX_VELOCITY_MM_S;
  c.accel_min_mm_s2 = AMZ_ACCEL_MIN_MM_S2;
  c.accel_max_mm_s2 = AMZ_ACCEL_MAX_MM_S2;
  c.battery.vref_mv = AMZ_BATTERY_VREF_MV;
  c.battery.divider_num = AMZ_BATTERY_DIVIDER_NUM;
  c.battery.divider_den = AMZ_BATTERY_DIVIDER_DEN;
  c.battery.adc_full_scale = AMZ_BATTERY_ADC_FULL_SCALE;
  c.battery_median_window = AMZ_BATTERY_MEDIAN_WINDOW;
  c.low_battery_10mv = AMZ_LOW_BATTERY_10MV;
  c.low_battery_hysteresis_10mv = AMZ_LOW_BATTERY_HYSTERESIS_10MV;
  c.gps_stale_ms = AMZ_GPS_STALE_MS;
  c.wheel_stale_ms = AMZ_WHEEL_STALE_MS;
  return c;
}

void RobotApp::init(const RobotConfig& config, uint32_t now_ms, bool e_stop_latched,
                    bool watchdog_reset) {
  config_ = config;
  config_.build_id[kBuildIdSize] = 0;
  if (config_.accel_min_mm_s2 == 0) config_.accel_min_mm_s2 = 1;
  if (config_.accel_max_mm_s2 < config_.accel_min_mm_s2) {
    config_.accel_max_mm_s2 = config_.accel_min_mm_s2;
  }
  // The compiled defaults obey the hard limits too.
  MotionConfig motion = config_.motion;
  if (motion.max_velocity_mm_s > config_.hard_max_velocity_mm_s) {
    motion.max_velocity_mm_s = config_.hard_max_velocity_mm_s;
  }
  if (motion.accel_mm_s2 < config_.accel_min_mm_s2) motion.accel_mm_s2 = config_.accel_min_mm_s2;
  if (motion.accel_mm_s2 > config_.accel_max_mm_s2) motion.accel_mm_s2 = config_.accel_max_mm_s2;
  motion_.init(motion, now_ms, e_stop_latched);
  battery_filter_.init(config_.battery_median_window);
  nmea_.reset();
  fix_.utc_ms_of_day = kNoUtcTime;
  fix_.lat_e7 = 0;
  fix_.lon_e7 = 0;
  fix_.quality = 0;
  fix_.satellites = 0;
  fix_.has_position = false;
  fix_ms_ = now_ms;
  wheel_ms_ = now_ms;
  wheel_mm_s_ = 0;
  battery_10mv_ = 0;
  telemetry_seq_ = 0;
  frames_rejected_ = 0;
  have_fix_ = false;
  have_wheel_ = false;
  low_battery_ = false;
  watchdog_reset_ = watchdog_reset;
}

size_t RobotApp::handle_frame(uint32_t now_ms, const uint8_t* data, size_t len, int8_t rssi_dbm,
                              uint8_t* reply, size_t reply_cap) {
  Frame frame;
  if (decode_frame(data, len, &frame) != FRAME_OK) {
    ++frames_rejected_;
    return 0;
  }
  size_t written = 0;
  if (frame.type == FRAME_COMMAND) {
    const CommandFrame& command = frame.command;
    const bool to_me = command.to_node == config_.node;
    if (!to_me && command.to_node != kBroadcastNode) return 0;
    const bool trusted = to_me && command.from_node == config_.base_node;
    motion_.on_command(command, now_ms, trusted);
    // Broadcasts are not answered (several robots would collide); nor are strangers.
    if (!trusted) return 0;
    TelemetryFrame t = telemetry(now_ms, command.from_node, rssi_dbm);
    if (encode_telemetry(t, reply, reply_cap, &written) != FRAME_OK) return 0;
    ++telemetry_seq_;
    return written;
  }
  if (frame.type == FRAME_CONFIG) {
    const ConfigFrame& request = frame.config;
    if (request.to_node != config_.node || request.from_node != config_.base_node) return 0;
    uint16_t max_v = request.max_velocity_mm_s;
    if (max_v > config_.hard_max_velocity_mm_s) max_v = config_.hard_max_velocity_mm_s;
    uint16_t accel = request.accel_mm_s2;
    if (accel < config_.accel_min_mm_s2) accel = config_.accel_min_mm_s2;
    if (accel > config_.accel_max_mm_s2) accel = config_.accel_max_mm_s2;
    motion_.set_limits(max_v, accel);
    // The acknowledgement carries the hard maximum too: the base station refuses to run
    // with a configured limit this robot would never reach.
    ConfigAckFrame answer;
    answer.to_node = request.from_node;
    answer.from_node = config_.node;
    answer.seq = request.seq;
    answer.max_velocity_mm_s = max_v;
    answer.accel_mm_s2 = accel;
    answer.hard_max_velocity_mm_s = config_.hard_max_velocity_mm_s;
    if (encode_config_ack(answer, reply, reply_cap, &written) != FRAME_OK) return 0;
    return written;
  }
  if (frame.type == FRAME_IDENTIFY) {
    const IdentifyFrame& request = frame.identify;
    if (request.to_node != config_.node || request.from_node != config_.base_node) return 0;
    IdentityFrame answer;
    answer.to_node = request.from_node;
    answer.from_node = config_.node;
    answer.seq = request.seq;
    for (uint8_t i = 0; i <= kBuildIdSize; ++i) answer.build_id[i] = config_.build_id[i];
    // The compiled-in configuration, as init() received it: what this build does by itself.
    answer.hard_max_velocity_mm_s = config_.hard_max_velocity_mm_s;
    answer.max_velocity_mm_s = config_.motion.max_velocity_mm_s;
    answer.accel_mm_s2 = config_.motion.accel_mm_s2;
    answer.accel_min_mm_s2 = config_.accel_min_mm_s2;
    answer.accel_max_mm_s2 = config_.accel_max_mm_s2;
    answer.stop_decel_mm_s2 = config_.motion.stop_decel_mm_s2;
    answer.dead_man_ms = config_.motion.dead_man_ms;
    answer.reverse_dwell_ms = config_.motion.reverse_dwell_ms;
    answer.full_scale_mm_s = config_.motion.full_scale_mm_s;
    answer.low_battery_10mv = config_.low_battery_10mv;
    answer.gps_stale_ms = config_.gps_stale_ms;
    answer.battery_median_window = config_.battery_median_window;
    if (encode_identity(answer, reply, reply_cap, &written) != FRAME_OK) return 0;
    return written;
  }
  return 0;  // telemetry, acknowledgements and identities are not for the robot
}

MotionOutput RobotApp::step(uint32_t now_ms) { return motion_.step(now_ms); }

void RobotApp::add_battery_sample(uint16_t adc_counts) {
  battery_filter_.add(battery_counts_to_10mv(adc_counts, config_.battery));
  battery_10mv_ = battery_filter_.median();
  if (!low_battery_ && battery_10mv_ < config_.low_battery_10mv) {
    low_battery_ = true;
  } else if (low_battery_ && static_cast<uint32_t>(battery_10mv_) >=
                                 static_cast<uint32_t>(config_.low_battery_10mv) +
                                     config_.low_battery_hysteresis_10mv) {
    low_battery_ = false;
  }
}

void RobotApp::feed_gps(uint32_t now_ms, char c) {
  NmeaResult result;
  GgaFix fix;
  if (nmea_.feed(c, &result, &fix) && result == NMEA_OK) {
    if (!fix.has_position) {  // keep the last known position; quality says it is not current
      fix.lat_e7 = fix_.lat_e7;
      fix.lon_e7 = fix_.lon_e7;
    }
    fix_ = fix;
    fix_ms_ = now_ms;
    have_fix_ = true;
  }
}

void RobotApp::set_measured_velocity(uint32_t now_ms, uint16_t velocity_mm_s) {
  wheel_mm_s_ = velocity_mm_s;
  wheel_ms_ = now_ms;
  have_wheel_ = true;
}

bool RobotApp::gps_fresh(uint32_t now_ms) const {
  return have_fix_ && static_cast<uint32_t>(now_ms - fix_ms_) < config_.gps_stale_ms;
}

uint8_t RobotApp::status(uint32_t now_ms) const {
  uint8_t s = motion_.status(now_ms);
  if (low_battery_) s |= ST_LOW_BATTERY;
  if (!gps_fresh(now_ms)) s |= ST_GPS_STALE;
  if (watchdog_reset_) s |= ST_WATCHDOG_RESET;
  return s;
}

TelemetryFrame RobotApp::telemetry(uint32_t now_ms, uint8_t to_node, int8_t rssi_dbm) const {
  TelemetryFrame t;
  t.to_node = to_node;
  t.from_node = config_.node;
  t.seq = telemetry_seq_;
  t.echo_seq = motion_.last_seq();
  t.robot_clock_ms = now_ms;
  const bool wheel_fresh =
      have_wheel_ && static_cast<uint32_t>(now_ms - wheel_ms_) < config_.wheel_stale_ms;
  t.velocity_mm_s = wheel_fresh ? wheel_mm_s_ : motion_.speed_mm_s();
  t.direction = motion_.direction();
  t.battery_10mv = battery_10mv_;
  t.lat_e7 = fix_.lat_e7;
  t.lon_e7 = fix_.lon_e7;
  t.fix_quality = gps_fresh(now_ms) && fix_.has_position ? wire_fix_quality(fix_.quality) : 0;
  t.satellites = gps_fresh(now_ms) ? fix_.satellites : 0;
  t.status = status(now_ms);
  t.rssi_dbm = rssi_dbm;
  return t;
}

}  // namespace amz
