// The robot's logic without its hardware: frames in, reply frames and motor output out,
// plus the sensors (battery counts, NMEA bytes, wheel speed, local stop input). The Arduino
// sketch and the host simulator (through the C API) drive the same code.
#ifndef AMZ_ROBOT_APP_H
#define AMZ_ROBOT_APP_H

#include <stddef.h>
#include <stdint.h>

#include "battery.h"
#include "motion.h"
#include "nmea.h"
#include "protocol.h"

namespace amz {

struct RobotConfig {
  char build_id[kBuildIdSize + 1];  // NUL-terminated, reported in the identity frame
  uint8_t node;
  uint8_t base_node;
  MotionConfig motion;
  uint16_t hard_max_velocity_mm_s;
  uint16_t accel_min_mm_s2;
  uint16_t accel_max_mm_s2;
  BatteryConfig battery;
  uint8_t battery_median_window;
  uint16_t low_battery_10mv;
  uint16_t low_battery_hysteresis_10mv;
  uint16_t gps_stale_ms;
  uint16_t wheel_stale_ms;
};

// The compiled-in configuration of robot_config.h.
RobotConfig default_robot_config();

class RobotApp {
 public:
  void init(const RobotConfig& config, uint32_t now_ms, bool e_stop_latched,
            bool watchdog_reset);

  // One frame from the radio (length byte first) with the RSSI it arrived at. Returns the
  // length of the reply written to `reply` (0: send nothing).
  size_t handle_frame(uint32_t now_ms, const uint8_t* frame, size_t len, int8_t rssi_dbm,
                      uint8_t* reply, size_t reply_cap);

  MotionOutput step(uint32_t now_ms);

  void add_battery_sample(uint16_t adc_counts);
  // Bytes from the GPS UART.
  void feed_gps(uint32_t now_ms, char c);
  void set_local_stop(bool open) { motion_.set_local_stop(open); }
  // From a wheel sensor, if fitted; without one the applied speed is reported.
  void set_measured_velocity(uint32_t now_ms, uint16_t velocity_mm_s);

  bool e_stop_latched() const { return motion_.e_stop_latched(); }
  uint16_t battery_10mv() const { return battery_10mv_; }
  uint8_t status(uint32_t now_ms) const;
  const GgaFix& gps_fix() const { return fix_; }
  const MotionController& motion() const { return motion_; }
  uint16_t frames_rejected() const { return frames_rejected_; }
  // The telemetry the robot would send now (sequence number not advanced).
  TelemetryFrame telemetry(uint32_t now_ms, uint8_t to_node, int8_t rssi_dbm) const;

 private:
  bool gps_fresh(uint32_t now_ms) const;

  RobotConfig config_;
  MotionController motion_;
  MedianFilter battery_filter_;
  NmeaReader nmea_;
  GgaFix fix_;
  uint32_t fix_ms_;
  uint32_t wheel_ms_;
  uint16_t wheel_mm_s_;
  uint16_t battery_10mv_;
  uint16_t telemetry_seq_;
  uint16_t frames_rejected_;
  bool have_fix_;
  bool have_wheel_;
  bool low_battery_;
  bool watchdog_reset_;
};

}  // namespace amz

#endif
