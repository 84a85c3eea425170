// Motion controller: turns command frames and time into a motor duty and direction while
// holding the robot safety invariants of docs/DESIGN.md §4 on the robot itself:
//   - no fresh command for dead_man_ms (500) -> ramp to zero; a command's own time-to-live
//     ends it earlier;
//   - speed clamped to the configured maximum; every change of speed limited by a ramp;
//   - direction changes only through zero (and after a dwell at zero);
//   - the e-stop latches (drive removed at once) until an explicit release.
// Velocity is kept signed in micrometres per second (+ = CW, - = CCW) so that the ramp is
// exact at 1 ms steps: accel [mm/s^2] * dt [ms] = delta [um/s].
#ifndef AMZ_MOTION_H
#define AMZ_MOTION_H

#include <stdint.h>

#include "protocol.h"

namespace amz {

struct MotionConfig {
  uint16_t max_velocity_mm_s;  // clamp for commanded speed
  uint16_t accel_mm_s2;        // ramp for every commanded change
  uint16_t stop_decel_mm_s2;   // dead-man / time-to-live stops use max(accel, this)
  uint16_t dead_man_ms;        // 500 by design
  uint16_t reverse_dwell_ms;   // time at zero before driving the other way
  uint16_t full_scale_mm_s;    // speed at duty_max
  uint8_t duty_min;            // smallest duty that moves the wheel (throttle dead band)
  uint8_t duty_max;            // duty at full_scale_mm_s
};

struct MotionOutput {
  uint8_t duty;           // 0..255 PWM duty for the motor driver
  uint8_t direction;      // DIR_CW / DIR_CCW; changes only while duty == 0
  bool drive_enabled;     // false while the e-stop is latched
  int32_t velocity_mm_s;  // signed applied speed, + = CW
};

// What on_command did, as bits.
enum CommandEvent {
  EV_ACCEPTED = 0x01,     // a newer command: echoed, refreshes the dead-man
  EV_STALE = 0x02,        // seq not newer while the link is fresh: ignored for motion
  EV_E_STOP = 0x04,       // the e-stop latched (or was already latched and is re-affirmed)
  EV_RELEASED = 0x08,     // the e-stop latch was released
  EV_RELEASE_REFUSED = 0x10,  // release asked but the local stop input is open
  EV_CLAMPED = 0x20,      // the velocity asked for exceeded the maximum
  EV_UNTRUSTED = 0x40     // not from the base station: only E_STOP is obeyed
};

class MotionController {
 public:
  void init(const MotionConfig& config, uint32_t now_ms, bool e_stop_latched);

  // A decoded command. `trusted` = addressed to this robot by its base station; an
  // untrusted frame (broadcast, another sender) can only latch the e-stop.
  uint8_t on_command(const CommandFrame& command, uint32_t now_ms, bool trusted);

  // Advance to now_ms and return what the motor must do. Call often (every loop).
  MotionOutput step(uint32_t now_ms);

  void latch_e_stop();
  // The robot's local stop input: open latches the e-stop and blocks its release.
  void set_local_stop(bool open);
  // New limits (already checked against the robot's hard limits by the caller).
  void set_limits(uint16_t max_velocity_mm_s, uint16_t accel_mm_s2);

  bool e_stop_latched() const { return e_stop_; }
  bool has_accepted_command() const { return ever_accepted_; }
  uint16_t last_seq() const { return last_seq_; }
  // ST_E_STOP_LATCHED, ST_DEAD_MAN, ST_TTL_EXPIRED, ST_CLAMPED, ST_LOCAL_STOP at now_ms.
  uint8_t status(uint32_t now_ms) const;
  int32_t velocity_um_s() const { return v_um_s_; }
  uint16_t speed_mm_s() const;
  uint8_t direction() const { return direction_; }
  const MotionConfig& config() const { return config_; }

 private:
  bool command_fresh(uint32_t now_ms) const;  // within the dead-man window
  bool command_live(uint32_t now_ms) const;   // fresh and within its time-to-live
  uint8_t duty_for(int32_t v_um_s) const;

  MotionConfig config_;
  int32_t v_um_s_;
  int32_t target_mm_s_;  // signed, clamped at receipt
  uint32_t last_step_ms_;
  uint32_t command_ms_;
  uint32_t zero_since_ms_;
  uint16_t ttl_ms_;
  uint16_t last_seq_;
  uint8_t direction_;
  bool has_command_;  // a command is inside its dead-man window (cleared once expired)
  bool ever_accepted_;
  bool e_stop_;
  bool local_stop_;
  bool clamped_;
};

}  // namespace amz

#endif
