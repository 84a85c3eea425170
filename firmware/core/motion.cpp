#include "motion.h"

namespace amz {
namespace {

// A step longer than this is treated as this long: bounds the products below and a
// stalled caller cannot turn one step into an unbounded jump.
const uint32_t kMaxStepMs = 10000;

int32_t abs32(int32_t v) { return v < 0 ? -v : v; }

}  // namespace

void MotionController::init(const MotionConfig& config, uint32_t now_ms, bool e_stop_latched) {
  config_ = config;
  if (config_.accel_mm_s2 == 0) config_.accel_mm_s2 = 1;
  if (config_.full_scale_mm_s == 0) config_.full_scale_mm_s = 1;
  if (config_.duty_max < config_.duty_min) config_.duty_max = config_.duty_min;
  v_um_s_ = 0;
  target_mm_s_ = 0;
  last_step_ms_ = now_ms;
  command_ms_ = now_ms;
  zero_since_ms_ = now_ms;
  ttl_ms_ = 0;
  last_seq_ = 0;
  direction_ = DIR_CW;
  has_command_ = false;
  ever_accepted_ = false;
  e_stop_ = e_stop_latched;
  local_stop_ = false;
  clamped_ = false;
}

void MotionController::latch_e_stop() {
  // The drive is removed at the next step() (the caller steps right after every input).
  e_stop_ = true;
  target_mm_s_ = 0;
}

void MotionController::set_local_stop(bool open) {
  local_stop_ = open;
  if (open) latch_e_stop();
}

void MotionController::set_limits(uint16_t max_velocity_mm_s, uint16_t accel_mm_s2) {
  config_.max_velocity_mm_s = max_velocity_mm_s;
  config_.accel_mm_s2 = accel_mm_s2 == 0 ? 1 : accel_mm_s2;
}

bool MotionController::command_fresh(uint32_t now_ms) const {
  return has_command_ && static_cast<uint32_t>(now_ms - command_ms_) < config_.dead_man_ms;
}

bool MotionController::command_live(uint32_t now_ms) const {
  return command_fresh(now_ms) && static_cast<uint32_t>(now_ms - command_ms_) < ttl_ms_;
}

uint8_t MotionController::on_command(const CommandFrame& command, uint32_t now_ms,
                                     bool trusted) {
  uint8_t events = 0;
  const bool e_stop = (command.flags & CMD_E_STOP) != 0;
  if (e_stop) {
    latch_e_stop();
    events |= EV_E_STOP;
  }
  if (!trusted) return static_cast<uint8_t>(events | EV_UNTRUSTED);

  // Duplicated or reordered frames must not bring back an old velocity; after a dead-man
  // timeout any seq starts a new exchange (a restarted base station is not locked out).
  if (command_fresh(now_ms) && !seq_newer(last_seq_, command.seq)) {
    return static_cast<uint8_t>(events | EV_STALE);
  }
  events |= EV_ACCEPTED;
  has_command_ = true;
  ever_accepted_ = true;
  last_seq_ = command.seq;
  command_ms_ = now_ms;
  ttl_ms_ = command.ttl_ms < config_.dead_man_ms ? command.ttl_ms : config_.dead_man_ms;

  if (e_stop) {
    target_mm_s_ = 0;
    return events;
  }
  if ((command.flags & CMD_E_STOP_RELEASE) != 0) {
    // The release frame's own velocity is ignored: motion resumes only on a later
    // command, ramping from zero.
    target_mm_s_ = 0;
    if (local_stop_) return static_cast<uint8_t>(events | EV_RELEASE_REFUSED);
    if (e_stop_) {
      events |= EV_RELEASED;
      zero_since_ms_ = now_ms;  // the wheel may still coast: a reversal waits the dwell
    }
    e_stop_ = false;
    return events;
  }
  uint16_t speed = command.velocity_mm_s;
  clamped_ = speed > config_.max_velocity_mm_s;
  if (clamped_) {
    speed = config_.max_velocity_mm_s;
    events |= EV_CLAMPED;
  }
  target_mm_s_ = command.direction == DIR_CW ? static_cast<int32_t>(speed)
                                             : -static_cast<int32_t>(speed);
  return events;
}

MotionOutput MotionController::step(uint32_t now_ms) {
  uint32_t dt = static_cast<uint32_t>(now_ms - last_step_ms_);
  if (dt > kMaxStepMs) dt = kMaxStepMs;
  last_step_ms_ = now_ms;

  // Forget an expired command for good, so that a 49.7-day wrap of the clock cannot make
  // it fresh again.
  if (has_command_ && !command_fresh(now_ms)) has_command_ = false;

  MotionOutput out;
  if (e_stop_) {
    if (v_um_s_ != 0) zero_since_ms_ = now_ms;
    v_um_s_ = 0;
    out.duty = 0;
    out.direction = direction_;
    out.drive_enabled = false;
    out.velocity_mm_s = 0;
    return out;
  }

  const bool live = command_live(now_ms);
  int32_t max_mm_s = static_cast<int32_t>(config_.max_velocity_mm_s);
  int32_t goal = live ? target_mm_s_ : 0;
  if (goal > max_mm_s) goal = max_mm_s;  // limits may have been lowered since receipt
  if (goal < -max_mm_s) goal = -max_mm_s;
  goal *= 1000;  // um/s

  uint32_t rate = config_.accel_mm_s2;
  if (!live && config_.stop_decel_mm_s2 > rate) rate = config_.stop_decel_mm_s2;

  // Reversal goes through zero, and waits at zero for the dwell time.
  if ((v_um_s_ > 0 && goal < 0) || (v_um_s_ < 0 && goal > 0)) goal = 0;
  if (v_um_s_ == 0 && goal != 0) {
    const uint8_t wanted = goal > 0 ? DIR_CW : DIR_CCW;
    if (wanted != direction_ &&
        static_cast<uint32_t>(now_ms - zero_since_ms_) < config_.reverse_dwell_ms) {
      goal = 0;
    }
  }

  const int32_t max_delta = static_cast<int32_t>(rate * dt);  // <= 1e4 * 1e4
  const int32_t before = v_um_s_;
  if (goal > v_um_s_) {
    v_um_s_ = (goal - v_um_s_ > max_delta) ? v_um_s_ + max_delta : goal;
  } else if (goal < v_um_s_) {
    v_um_s_ = (v_um_s_ - goal > max_delta) ? v_um_s_ - max_delta : goal;
  }
  if (v_um_s_ != 0) {
    direction_ = v_um_s_ > 0 ? DIR_CW : DIR_CCW;
  } else if (before != 0) {
    zero_since_ms_ = now_ms;
  }

  out.duty = duty_for(v_um_s_);
  out.direction = direction_;
  out.drive_enabled = true;
  out.velocity_mm_s = v_um_s_ / 1000;
  return out;
}

uint8_t MotionController::duty_for(int32_t v_um_s) const {
  const uint32_t speed_mm_s = static_cast<uint32_t>(abs32(v_um_s)) / 1000UL;
  if (speed_mm_s == 0) return 0;  // below 1 mm/s the wheel stands
  const uint32_t full_mm_s = config_.full_scale_mm_s;
  if (speed_mm_s >= full_mm_s) return config_.duty_max;
  const uint32_t span = static_cast<uint32_t>(config_.duty_max - config_.duty_min);
  // speed_mm_s < 65536 and span <= 255: the product fits in 32 bits.
  const uint32_t scaled = (speed_mm_s * span + full_mm_s / 2) / full_mm_s;
  return static_cast<uint8_t>(config_.duty_min + scaled);
}

uint16_t MotionController::speed_mm_s() const {
  return static_cast<uint16_t>((abs32(v_um_s_) + 500) / 1000);
}

uint8_t MotionController::status(uint32_t now_ms) const {
  uint8_t s = 0;
  if (e_stop_) s |= ST_E_STOP_LATCHED;
  if (local_stop_) s |= ST_LOCAL_STOP;
  if (!command_fresh(now_ms)) {
    s |= ST_DEAD_MAN;
  } else if (!command_live(now_ms)) {
    s |= ST_TTL_EXPIRED;
  }
  if (clamped_) s |= ST_CLAMPED;
  return s;
}

}  // namespace amz
