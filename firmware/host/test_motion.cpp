// Safety invariants of the motion controller (DESIGN.md §4 "Robot safety invariants").
#include "harness.h"
#include "motion.h"

using namespace amz;

namespace {

MotionConfig test_config() {
  MotionConfig c;
  c.max_velocity_mm_s = 2000;
  c.accel_mm_s2 = 250;
  c.stop_decel_mm_s2 = 500;
  c.dead_man_ms = 500;
  c.reverse_dwell_ms = 250;
  c.full_scale_mm_s = 8333;
  c.duty_min = 0;
  c.duty_max = 255;
  return c;
}

// Drives a controller in time and checks the invariants after every step:
//   |dv| <= max(accel, stop_decel) * dt (the e-stop alone may cut to zero at once),
//   |v| <= max velocity, the direction output changes only after duty 0 held at zero for
//   the reverse dwell, and the velocity never changes sign without being zero.
struct Rig {
  MotionController c;
  MotionConfig config;
  uint32_t now;
  uint16_t seq;
  MotionOutput out;
  uint32_t zero_since;
  int steps;

  explicit Rig(uint32_t start_ms = 0, bool latched = false) {
    config = test_config();
    now = start_ms;
    seq = 0;
    c.init(config, now, latched);
    out = c.step(now);
    zero_since = now;
    steps = 0;
  }

  uint8_t send(uint16_t v, uint8_t dir, uint8_t flags = 0, uint16_t ttl = 500) {
    ++seq;
    return send_seq(seq, v, dir, flags, ttl);
  }

  uint8_t send_seq(uint16_t s, uint16_t v, uint8_t dir, uint8_t flags = 0, uint16_t ttl = 500,
                   bool trusted = true) {
    CommandFrame f = {2, 1, s, v, dir, flags, ttl};
    return c.on_command(f, now, trusted);
  }

  void step(uint32_t dt) {
    const MotionOutput before = out;
    const int32_t v_before = c.velocity_um_s();
    now += dt;
    out = c.step(now);
    ++steps;
    const int32_t v = c.velocity_um_s();
    const uint32_t rate = config.accel_mm_s2 > config.stop_decel_mm_s2 ? config.accel_mm_s2
                                                                       : config.stop_decel_mm_s2;
    const int64_t dv = static_cast<int64_t>(v) - v_before;
    if (!c.e_stop_latched()) {
      CHECK_MSG((dv < 0 ? -dv : dv) <= static_cast<int64_t>(rate) * dt, "ramp exceeded");
    } else {
      CHECK_EQ(out.duty, 0);
      CHECK(!out.drive_enabled);
    }
    CHECK_MSG(v <= static_cast<int32_t>(config.max_velocity_mm_s) * 1000 &&
                  v >= -static_cast<int32_t>(config.max_velocity_mm_s) * 1000,
              "velocity over the maximum");
    CHECK_MSG(!((v_before > 0 && v < 0) || (v_before < 0 && v > 0)), "sign change skipped zero");
    if (out.direction != before.direction) {
      CHECK_MSG(before.duty == 0 && v_before == 0, "direction changed while driving");
      CHECK_MSG(now - zero_since >= config.reverse_dwell_ms, "reversed without the dwell");
    }
    if (v_before != 0 && v == 0) zero_since = now;
    if (out.duty > 0) {
      CHECK_EQ(out.direction, v > 0 ? DIR_CW : DIR_CCW);
    }
  }

  // Run for `ms`, stepping every `dt`, re-sending (v, dir) every `period` ms if period > 0.
  void run(uint32_t ms, uint32_t dt = 10, uint32_t period = 0, uint16_t v = 0,
           uint8_t dir = DIR_CW, uint16_t ttl = 500) {
    uint32_t since_send = 0;
    for (uint32_t t = 0; t < ms; t += dt) {
      if (period != 0 && since_send >= period) {
        send(v, dir, 0, ttl);
        since_send = 0;
      }
      step(dt);
      since_send += dt;
    }
  }

  int32_t v_mm_s() const { return c.velocity_um_s() / 1000; }
};

}  // namespace

TEST(starts_stopped_with_dead_man_flag) {
  Rig r;
  r.run(1000);
  CHECK_EQ(r.out.duty, 0);
  CHECK(r.out.drive_enabled);
  CHECK(r.c.status(r.now) & ST_DEAD_MAN);
}

TEST(ramps_up_at_the_configured_acceleration) {
  Rig r;
  r.send(1000, DIR_CW);
  r.run(1000, 10, 100, 1000, DIR_CW);
  // 250 mm/s^2 for 1 s.
  CHECK_EQ(r.c.velocity_um_s(), 250000);
  r.run(3000, 10, 100, 1000, DIR_CW);
  CHECK_EQ(r.v_mm_s(), 1000);
  CHECK_EQ(r.out.direction, DIR_CW);
  CHECK_EQ(r.out.duty, (1000 * 255 + 8333 / 2) / 8333);
  CHECK_EQ(r.c.status(r.now) & (ST_DEAD_MAN | ST_TTL_EXPIRED), 0);
}

TEST(dead_man_stops_500_ms_after_the_last_command) {
  Rig r;
  r.send(1000, DIR_CW, 0, 65535);
  r.run(5000, 10, 100, 1000, DIR_CW, 65535);
  CHECK_EQ(r.v_mm_s(), 1000);
  // The run() loop sent its last command 100 ms before its end at most; send one now.
  r.send(1000, DIR_CW, 0, 65535);
  const uint32_t last = r.now;
  while (r.now - last < 490) r.step(10);
  CHECK_EQ(r.v_mm_s(), 1000);  // still fresh at 490 ms
  CHECK_EQ(r.c.status(r.now) & ST_DEAD_MAN, 0);
  r.step(10);  // 500 ms: the dead-man
  CHECK(r.c.status(r.now) & ST_DEAD_MAN);
  CHECK(r.c.velocity_um_s() < 1000000);
  // Stops within 1000 mm/s / 500 mm/s^2 = 2 s, at the stop deceleration.
  while (r.now - last < 500 + 2000) r.step(10);
  CHECK_EQ(r.c.velocity_um_s(), 0);
  CHECK_EQ(r.out.duty, 0);
}

TEST(dead_man_holds_with_a_1_ms_loop) {
  Rig r;
  r.send(800, DIR_CCW);
  r.run(4000, 1, 100, 800, DIR_CCW);
  CHECK_EQ(r.v_mm_s(), -800);
  const uint32_t last = r.now;  // run() sent at most 100 ms ago
  r.run(2500, 1);
  CHECK_EQ(r.c.velocity_um_s(), 0);
  CHECK(r.now - last <= 500 + 1600 + 100 + 2500);
}

TEST(time_to_live_ends_a_command_before_the_dead_man) {
  Rig r;
  r.send(1000, DIR_CW);
  r.run(5000, 10, 100, 1000, DIR_CW);
  r.send(1000, DIR_CW, 0, 200);
  const uint32_t sent = r.now;
  while (r.now - sent < 190) r.step(10);
  CHECK_EQ(r.v_mm_s(), 1000);
  r.step(10);  // 200 ms
  CHECK(r.c.status(r.now) & ST_TTL_EXPIRED);
  CHECK_EQ(r.c.status(r.now) & ST_DEAD_MAN, 0);
  r.step(10);
  CHECK(r.c.velocity_um_s() < 1000000);
  while (r.now - sent < 500) r.step(10);
  CHECK(r.c.status(r.now) & ST_DEAD_MAN);
  CHECK_EQ(r.c.status(r.now) & ST_TTL_EXPIRED, 0);
}

TEST(time_to_live_zero_is_a_stop) {
  Rig r;
  r.send(1000, DIR_CW);
  r.run(5000, 10, 100, 1000, DIR_CW);
  r.run(3000, 10, 100, 1000, DIR_CW, 0);
  CHECK_EQ(r.c.velocity_um_s(), 0);
  CHECK(r.c.status(r.now) & ST_TTL_EXPIRED);
}

TEST(time_to_live_never_exceeds_the_dead_man) {
  Rig r;
  r.send(400, DIR_CW, 0, 65535);
  r.run(200, 10);
  CHECK(r.c.velocity_um_s() > 0);
  r.run(400, 10);  // 600 ms after the command
  CHECK(r.c.status(r.now) & ST_DEAD_MAN);
  r.run(2000, 10);
  CHECK_EQ(r.c.velocity_um_s(), 0);
}

TEST(velocity_is_clamped_to_the_maximum) {
  Rig r;
  CHECK(r.send(5000, DIR_CW) & EV_CLAMPED);
  r.run(15000, 10, 100, 5000, DIR_CW);
  CHECK_EQ(r.v_mm_s(), 2000);
  CHECK(r.c.status(r.now) & ST_CLAMPED);
  CHECK(!(r.send(1000, DIR_CW) & EV_CLAMPED));
  CHECK_EQ(r.c.status(r.now) & ST_CLAMPED, 0);
}

TEST(lowered_limit_ramps_down_to_the_new_maximum) {
  Rig r;
  r.send(2000, DIR_CW);
  r.run(10000, 10, 100, 2000, DIR_CW);
  CHECK_EQ(r.v_mm_s(), 2000);
  r.c.set_limits(500, 250);
  r.config.max_velocity_mm_s = 2000;  // the rig keeps checking the old bound while ramping
  r.run(10000, 10, 100, 2000, DIR_CW);
  CHECK_EQ(r.v_mm_s(), 500);
}

TEST(reversal_goes_through_zero_and_waits_the_dwell) {
  Rig r;
  r.send(1000, DIR_CW);
  r.run(5000, 10, 100, 1000, DIR_CW);
  CHECK_EQ(r.v_mm_s(), 1000);
  bool saw_zero = false;
  for (int i = 0; i < 1200; ++i) {
    if (i % 10 == 0) r.send(1000, DIR_CCW);
    r.step(10);
    if (r.c.velocity_um_s() == 0) saw_zero = true;
  }
  CHECK(saw_zero);
  CHECK_EQ(r.v_mm_s(), -1000);
  CHECK_EQ(r.out.direction, DIR_CCW);
}

TEST(ramp_and_direction_rules_hold_under_random_commands) {
  Rig r(0xFFFF0000UL);  // also crosses the 32-bit millis() wrap
  uint32_t state = 99;
  for (int i = 0; i < 60000; ++i) {
    state = state * 1664525UL + 1013904223UL;
    const uint32_t pick = state >> 8;
    if (pick % 7 == 0) {
      const uint16_t v = static_cast<uint16_t>((pick >> 4) % 6000);
      const uint8_t dir = static_cast<uint8_t>((pick >> 3) & 1);
      const uint16_t ttl = static_cast<uint16_t>((pick >> 5) % 900);
      uint8_t flags = 0;
      if ((pick >> 12) % 400 == 0) flags = CMD_E_STOP;
      if ((pick >> 12) % 400 == 1) flags = CMD_E_STOP_RELEASE;
      if ((pick >> 20) % 50 == 0) {
        r.send_seq(static_cast<uint16_t>(pick), v, dir, flags, ttl);  // random seq
      } else {
        r.send(v, dir, flags, ttl);
      }
    }
    r.step(1 + (pick >> 16) % 40);
  }
  CHECK(r.steps > 50000);
}

TEST(e_stop_latches_and_cuts_drive_at_once) {
  Rig r;
  r.send(1500, DIR_CW);
  r.run(8000, 10, 100, 1500, DIR_CW);
  CHECK_EQ(r.v_mm_s(), 1500);
  CHECK(r.send(0, DIR_CW, CMD_E_STOP) & EV_E_STOP);
  r.step(1);
  CHECK_EQ(r.out.duty, 0);
  CHECK(!r.out.drive_enabled);
  CHECK(r.c.status(r.now) & ST_E_STOP_LATCHED);
  // Normal commands do not move a latched robot, for as long as it stays latched.
  r.run(5000, 10, 100, 1500, DIR_CW);
  CHECK_EQ(r.c.velocity_um_s(), 0);
  CHECK(r.c.e_stop_latched());
}

TEST(e_stop_release_needs_a_later_command_to_move) {
  Rig r;
  r.send(0, DIR_CW, CMD_E_STOP);
  r.step(10);
  CHECK(r.send(1500, DIR_CW, CMD_E_STOP_RELEASE) & EV_RELEASED);
  CHECK(!r.c.e_stop_latched());
  r.run(300, 10);
  CHECK_EQ(r.c.velocity_um_s(), 0);  // the release frame's velocity is ignored
  r.send(1000, DIR_CW);
  r.step(100);
  CHECK_EQ(r.c.velocity_um_s(), 25000);  // ramping from zero at 250 mm/s^2
}

TEST(e_stop_wins_over_release_in_the_same_frame) {
  Rig r;
  r.send(0, DIR_CW, CMD_E_STOP | CMD_E_STOP_RELEASE);
  r.step(10);
  CHECK(r.c.e_stop_latched());
}

TEST(e_stop_is_obeyed_from_stale_and_untrusted_frames) {
  Rig r;
  r.send(1000, DIR_CW);
  r.run(2000, 10, 100, 1000, DIR_CW);
  // A duplicate of an old frame carrying E_STOP still stops.
  CHECK(r.send_seq(1, 0, DIR_CW, CMD_E_STOP) & EV_E_STOP);
  CHECK(r.c.e_stop_latched());
  r.send(0, DIR_CW, CMD_E_STOP_RELEASE);
  CHECK(!r.c.e_stop_latched());
  // A broadcast or foreign frame can stop but cannot release.
  CHECK(r.send_seq(static_cast<uint16_t>(r.seq + 1), 0, DIR_CW, CMD_E_STOP, 500, false) &
        EV_E_STOP);
  CHECK(r.c.e_stop_latched());
  r.send_seq(static_cast<uint16_t>(r.seq + 2), 0, DIR_CW, CMD_E_STOP_RELEASE, 500, false);
  CHECK(r.c.e_stop_latched());
  // A stale release (old seq) is ignored too.
  r.send_seq(1, 0, DIR_CW, CMD_E_STOP_RELEASE);
  CHECK(r.c.e_stop_latched());
}

TEST(e_stop_latched_at_start_stays_latched) {
  Rig r(0, true);
  r.send(1000, DIR_CW);
  r.run(2000, 10, 100, 1000, DIR_CW);
  CHECK(r.c.e_stop_latched());
  CHECK_EQ(r.c.velocity_um_s(), 0);
}

TEST(local_stop_latches_and_blocks_release_while_open) {
  Rig r;
  r.send(1000, DIR_CW);
  r.run(2000, 10, 100, 1000, DIR_CW);
  r.c.set_local_stop(true);
  r.step(1);
  CHECK_EQ(r.out.duty, 0);
  CHECK(r.c.status(r.now) & ST_LOCAL_STOP);
  CHECK(r.send(0, DIR_CW, CMD_E_STOP_RELEASE) & EV_RELEASE_REFUSED);
  CHECK(r.c.e_stop_latched());
  r.c.set_local_stop(false);
  CHECK(r.c.e_stop_latched());  // closing the loop alone does not release
  CHECK(r.send(0, DIR_CW, CMD_E_STOP_RELEASE) & EV_RELEASED);
  CHECK(!r.c.e_stop_latched());
}

TEST(stale_and_duplicate_sequence_numbers_are_ignored) {
  Rig r;
  r.send_seq(10, 1000, DIR_CW);
  r.step(10);
  CHECK(r.send_seq(9, 0, DIR_CW) & EV_STALE);
  CHECK(r.send_seq(10, 0, DIR_CW) & EV_STALE);
  CHECK_EQ(r.c.last_seq(), 10);
  r.step(100);
  CHECK(r.c.velocity_um_s() > 0);
}

TEST(sequence_wrap_is_accepted) {
  Rig r;
  r.send_seq(65535, 500, DIR_CW);
  r.step(10);
  CHECK(r.send_seq(0, 500, DIR_CW) & EV_ACCEPTED);
  CHECK_EQ(r.c.last_seq(), 0);
}

TEST(any_sequence_is_accepted_after_the_dead_man) {
  Rig r;
  r.send_seq(1000, 500, DIR_CW);
  r.run(600, 10);
  CHECK(r.send_seq(5, 500, DIR_CW) & EV_ACCEPTED);
  CHECK_EQ(r.c.last_seq(), 5);
}

TEST(an_expired_command_stays_expired_across_the_clock_wrap) {
  MotionController c;
  c.init(test_config(), 0, false);
  CommandFrame f = {2, 1, 1, 1000, DIR_CW, 0, 500};
  c.on_command(f, 0, true);
  c.step(0);
  c.step(600);  // dead-man: forgotten
  // 2^32 ms later the clock reads 100 again: the old command must not come back.
  MotionOutput out = c.step(100);
  CHECK_EQ(out.duty, 0);
  out = c.step(300);
  CHECK_EQ(out.duty, 0);
  CHECK(c.status(300) & ST_DEAD_MAN);
}

TEST(duty_maps_speed_onto_the_driver_range) {
  MotionConfig cfg = test_config();
  cfg.max_velocity_mm_s = 9000;
  cfg.accel_mm_s2 = 30000;
  cfg.duty_min = 40;
  cfg.duty_max = 250;
  MotionController c;
  c.init(cfg, 0, false);
  c.step(0);
  CommandFrame f = {2, 1, 1, 8333, DIR_CCW, 0, 500};
  // After the reverse dwell counted from start-up (the controller starts facing CW).
  MotionOutput out = c.step(1000);
  CHECK_EQ(out.duty, 0);
  c.on_command(f, 1000, true);
  out = c.step(1001);  // 30 mm/s
  CHECK_EQ(out.duty, 40 + (30 * 210 + 8333 / 2) / 8333);
  out = c.step(1400);
  CHECK_EQ(out.velocity_mm_s, -8333);
  CHECK_EQ(out.duty, 250);
  CHECK_EQ(out.direction, DIR_CCW);
}
