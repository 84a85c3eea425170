// The robot as a whole through its C API: frames in, replies and motor output out.
#include <stdio.h>
#include <string.h>

#include "amazing_robot.h"
#include "harness.h"

namespace {

struct Robot {
  amz_robot* r;
  uint8_t reply[66];
  size_t reply_len;
  uint16_t seq;

  explicit Robot(int latched = 0, int watchdog = 0) : reply_len(0), seq(0) {
    amz_robot_config c;
    amz_robot_default_config(&c);
    r = amz_robot_create(&c, 0, latched, watchdog);
  }
  ~Robot() { amz_robot_destroy(r); }

  size_t command(uint32_t now, uint16_t v, uint8_t dir, uint8_t flags = 0, uint16_t ttl = 500,
                 uint8_t to = 2, uint8_t from = 1, int8_t rssi = -60) {
    amz_command c = {to, from, ++seq, v, dir, flags, ttl};
    uint8_t frame[66];
    const int len = amz_encode_command(&c, frame, sizeof frame);
    CHECK_EQ(len, 14);
    reply_len = amz_robot_handle_frame(r, now, frame, static_cast<size_t>(len), rssi, reply,
                                       sizeof reply);
    return reply_len;
  }

  amz_telemetry telemetry() {
    amz_frame f;
    memset(&f, 0, sizeof f);
    CHECK_EQ(amz_decode_frame(reply, reply_len, &f), AMZ_OK);
    CHECK_EQ(f.type, 2);
    return f.telemetry;
  }

  amz_motion_output step(uint32_t now) {
    amz_motion_output out;
    amz_robot_step(r, now, &out);
    return out;
  }

  void gps(uint32_t now, const char* body) {
    char buf[160];
    uint8_t sum = 0;
    for (const char* p = body; *p != '\0'; ++p) sum = static_cast<uint8_t>(sum ^ *p);
    snprintf(buf, sizeof buf, "$%s*%02X\r\n", body, sum);
    amz_robot_feed_gps(r, now, buf, strlen(buf));
  }
};

}  // namespace

TEST(capi_reports_its_abi_version) { CHECK_EQ(amz_abi_version(), AMZ_ABI_VERSION); }

TEST(command_is_answered_with_telemetry_echoing_its_seq) {
  Robot robot;
  CHECK_EQ(robot.command(0, 1000, 1, 0, 500, 2, 1, -71), 31);
  const amz_telemetry t = robot.telemetry();
  CHECK_EQ(t.to_node, 1);
  CHECK_EQ(t.from_node, 2);
  CHECK_EQ(t.seq, 0);
  CHECK_EQ(t.echo_seq, 1);
  CHECK_EQ(t.rssi_dbm, -71);
  CHECK_EQ(t.robot_clock_ms, 0);
  CHECK(t.status & 0x20);  // no GPS yet
  for (uint32_t now = 10; now <= 1000; now += 10) {
    robot.step(now);
    if (now % 100 == 0) robot.command(now, 1000, 1);
  }
  const amz_telemetry later = robot.telemetry();
  CHECK_EQ(later.seq, 10);  // one telemetry per command, numbered by the robot
  CHECK_EQ(later.echo_seq, 11);
  CHECK_EQ(later.velocity_mm_s, 250);  // no wheel sensor: the applied speed
  CHECK_EQ(later.direction, 1);
  CHECK_EQ(later.status & 0x02, 0);
}

TEST(default_reverse_dwell_outlasts_the_drive_lag) {
  amz_robot_config c;
  amz_robot_default_config(&c);
  CHECK_EQ(c.reverse_dwell_ms, 700);
  // A reversal at the default config: zero, then 700 ms at zero before the other way.
  Robot robot;
  uint32_t now = 0;
  for (; now <= 3000; now += 20) {
    robot.step(now);
    robot.command(now, 500, 1);
  }
  uint32_t zero_since = 0;
  bool reversed = false;
  for (; now <= 9000 && !reversed; now += 20) {
    const amz_motion_output out = robot.step(now);
    robot.command(now, 500, 0);
    if (out.velocity_mm_s == 0 && zero_since == 0) zero_since = now;
    if (out.velocity_mm_s < 0) {
      reversed = true;
      CHECK(zero_since != 0);
      CHECK(now - zero_since >= 700);
      CHECK(now - zero_since <= 700 + 40);
    }
  }
  CHECK(reversed);
}

TEST(commands_at_50_hz_are_each_answered_and_never_trip_the_dead_man) {
  // The agent's fastest rate: a command every 20 ms for 10 s, the motion stepped every ms.
  Robot robot;
  uint16_t answered = 0;
  for (uint32_t now = 0; now <= 10000; ++now) {
    const amz_motion_output out = robot.step(now);
    if (now % 20 == 0) {
      CHECK_EQ(robot.command(now, 1000, 1, 0, 100), 31);
      const amz_telemetry t = robot.telemetry();
      CHECK_EQ(t.echo_seq, robot.seq);
      CHECK(!(t.status & 0x02));  // never the dead-man
      CHECK(!(t.status & 0x04));  // nor a command's time-to-live
      ++answered;
    }
    if (now >= 5000) CHECK_EQ(out.velocity_mm_s, 1000);  // at speed, held
  }
  CHECK_EQ(answered, 501);
}

TEST(frames_for_others_or_malformed_are_not_answered) {
  Robot robot;
  CHECK_EQ(robot.command(0, 500, 1, 0, 500, 3, 1), 0);    // another robot
  CHECK_EQ(robot.command(0, 500, 1, 0, 500, 2, 9), 0);    // not our base station
  CHECK_EQ(robot.command(0, 500, 1, 0, 500, 255, 1), 0);  // broadcast: never answered
  const uint8_t junk[] = {0x0d, 0x02, 0x01, 0x00, 0x02, 0x01, 0, 0, 0, 0, 0, 0, 0, 0};
  uint8_t reply[66];
  CHECK_EQ(amz_robot_handle_frame(robot.r, 0, junk, sizeof junk, -50, reply, sizeof reply), 0);
  CHECK_EQ(amz_robot_handle_frame(robot.r, 0, 0, 0, -50, reply, sizeof reply), 0);
  // A robot's own telemetry coming back is ignored too.
  amz_telemetry t;
  memset(&t, 0, sizeof t);
  t.to_node = 2;
  uint8_t frame[66];
  const int len = amz_encode_telemetry(&t, frame, sizeof frame);
  CHECK_EQ(len, 31);
  CHECK_EQ(amz_robot_handle_frame(robot.r, 0, frame, 31, -50, reply, sizeof reply), 0);
  robot.step(100);
  CHECK_EQ(robot.step(200).duty, 0);  // nothing moved the robot
}

TEST(broadcast_e_stop_latches_without_reply) {
  Robot robot;
  robot.command(0, 1000, 1);
  for (uint32_t now = 10; now <= 2000; now += 10) {
    robot.step(now);
    if (now % 100 == 0) robot.command(now, 1000, 1);
  }
  CHECK(robot.step(2000).duty > 0);
  CHECK_EQ(robot.command(2001, 0, 0, 0x01, 0, 255, 7), 0);
  const amz_motion_output out = robot.step(2002);
  CHECK_EQ(out.duty, 0);
  CHECK_EQ(out.drive_enabled, 0);
  CHECK(out.status & 0x01);
  CHECK_EQ(amz_robot_e_stop_latched(robot.r), 1);
  // Released only by the base station.
  robot.command(2100, 0, 0, 0x02);
  CHECK_EQ(amz_robot_e_stop_latched(robot.r), 0);
  CHECK_EQ(robot.telemetry().status & 0x01, 0);
}

TEST(config_is_applied_within_the_hard_limits_and_answered) {
  Robot robot;
  amz_config request = {2, 1, 77, 9000, 5};
  uint8_t frame[66];
  const int len = amz_encode_config(&request, frame, sizeof frame);
  CHECK_EQ(len, 12);
  uint8_t reply[66];
  const size_t n =
      amz_robot_handle_frame(robot.r, 0, frame, static_cast<size_t>(len), -50, reply, sizeof reply);
  CHECK_EQ(n, 14);
  amz_frame f;
  CHECK_EQ(amz_decode_frame(reply, n, &f), AMZ_OK);
  CHECK_EQ(f.type, 4);  // a config acknowledgement
  CHECK_EQ(f.config_ack.seq, 77);
  CHECK_EQ(f.config_ack.to_node, 1);
  CHECK_EQ(f.config_ack.from_node, 2);
  CHECK_EQ(f.config_ack.max_velocity_mm_s, 4000);  // the hard maximum
  CHECK_EQ(f.config_ack.accel_mm_s2, 50);          // raised to the hard minimum
  CHECK_EQ(f.config_ack.hard_max_velocity_mm_s, 4000);  // reported, whatever was asked
  // The new limit holds: a 9 m/s command ends at 4 m/s.
  uint32_t now = 0;
  for (; now <= 120000; now += 20) {
    if (now % 100 == 0) robot.command(now, 9000, 1);
    robot.step(now);
  }
  CHECK_EQ(robot.step(now).velocity_mm_s, 4000);
}

namespace {

size_t identify(amz_robot* r, uint8_t to, uint8_t from, uint8_t* reply, size_t cap) {
  amz_identify request = {to, from, 4242};
  uint8_t frame[66];
  const int len = amz_encode_identify(&request, frame, sizeof frame);
  CHECK_EQ(len, 8);
  return amz_robot_handle_frame(r, 0, frame, static_cast<size_t>(len), -50, reply, cap);
}

}  // namespace

TEST(identify_is_answered_with_the_build_id_and_the_compiled_configuration) {
  amz_robot_config c;
  amz_robot_default_config(&c);
  CHECK(strcmp(c.build_id, AMZ_BUILD_ID) == 0);  // the Makefile's identifier
  strcpy(c.build_id, "bench-7");
  c.hard_max_velocity_mm_s = 3500;
  c.dead_man_ms = 400;
  amz_robot* r = amz_robot_create(&c, 0, 0, 0);
  uint8_t reply[66];
  const size_t n = identify(r, 2, 1, reply, sizeof reply);
  CHECK_EQ(n, 47);
  amz_frame f;
  memset(&f, 0, sizeof f);
  CHECK_EQ(amz_decode_frame(reply, n, &f), AMZ_OK);
  CHECK_EQ(f.type, 6);
  CHECK_EQ(f.identity.seq, 4242);
  CHECK_EQ(f.identity.to_node, 1);
  CHECK(strcmp(f.identity.build_id, "bench-7") == 0);
  CHECK_EQ(f.identity.hard_max_velocity_mm_s, 3500);
  CHECK_EQ(f.identity.max_velocity_mm_s, c.max_velocity_mm_s);
  CHECK_EQ(f.identity.accel_min_mm_s2, c.accel_min_mm_s2);
  CHECK_EQ(f.identity.dead_man_ms, 400);
  CHECK_EQ(f.identity.battery_median_window, c.battery_median_window);
  // Only its own base station is answered, and a full reply buffer gets nothing.
  CHECK_EQ(identify(r, 2, 9, reply, sizeof reply), 0);
  CHECK_EQ(identify(r, 3, 1, reply, sizeof reply), 0);
  CHECK_EQ(identify(r, 2, 1, reply, 46), 0);
  amz_robot_destroy(r);
}

TEST(gps_fix_is_reported_and_goes_stale) {
  Robot robot;
  robot.gps(0, "GNGGA,101530.20,4038.05032,N,00839.60090,W,4,14,0.62,32.1,M,50.2,M,1.0,0000");
  robot.command(100, 0, 0);
  amz_telemetry t = robot.telemetry();
  CHECK_EQ(t.lat_e7, 406341720L);
  CHECK_EQ(t.lon_e7, -86600150L);
  CHECK_EQ(t.fix_quality, 4);
  CHECK_EQ(t.satellites, 14);
  CHECK_EQ(t.status & 0x20, 0);
  robot.command(2500, 0, 0);  // 2.5 s without a sentence
  t = robot.telemetry();
  CHECK_EQ(t.fix_quality, 0);
  CHECK(t.status & 0x20);
  CHECK_EQ(t.lat_e7, 406341720L);  // last known position kept
  // A no-fix sentence keeps the last position but reports no fix.
  robot.gps(2600, "GNGGA,101533.00,,,,,0,00,99.99,,,,,,");
  robot.command(2700, 0, 0);
  t = robot.telemetry();
  CHECK_EQ(t.fix_quality, 0);
  CHECK_EQ(t.status & 0x20, 0);
  CHECK_EQ(t.lat_e7, 406341720L);
}

TEST(battery_is_median_filtered_with_low_battery_hysteresis) {
  Robot robot;
  for (int i = 0; i < 7; ++i) amz_robot_add_battery_sample(robot.r, 819);  // 59.99 V
  amz_robot_add_battery_sample(robot.r, 0);                                // a spike
  amz_robot_add_battery_sample(robot.r, 1023);                             // another
  CHECK_EQ(amz_robot_battery_10mv(robot.r), 5999);
  CHECK_EQ(amz_robot_status(robot.r, 0) & 0x10, 0);
  for (int i = 0; i < 7; ++i) amz_robot_add_battery_sample(robot.r, 710);  // 52.0 V
  CHECK(amz_robot_status(robot.r, 0) & 0x10);
  for (int i = 0; i < 7; ++i) amz_robot_add_battery_sample(robot.r, 720);  // 52.73 V
  CHECK(amz_robot_status(robot.r, 0) & 0x10);  // inside the hysteresis band
  for (int i = 0; i < 7; ++i) amz_robot_add_battery_sample(robot.r, 740);  // 54.2 V
  CHECK_EQ(amz_robot_status(robot.r, 0) & 0x10, 0);
  robot.command(0, 0, 0);
  CHECK_EQ(robot.telemetry().battery_10mv, amz_battery_counts_to_10mv(740, 5000, 15, 1, 1024));
}

TEST(wheel_sensor_speed_is_reported_while_fresh) {
  Robot robot;
  amz_robot_set_measured_velocity(robot.r, 0, 1234);
  robot.command(100, 0, 0);
  CHECK_EQ(robot.telemetry().velocity_mm_s, 1234);
  robot.command(700, 0, 0);
  CHECK_EQ(robot.telemetry().velocity_mm_s, 0);  // stale: the applied speed
}

TEST(restart_with_latched_e_stop_and_watchdog_flag) {
  Robot robot(1, 1);
  robot.command(0, 1000, 1);
  const amz_telemetry t = robot.telemetry();
  CHECK(t.status & 0x01);
  CHECK(t.status & 0x40);
  for (uint32_t now = 10; now <= 1000; now += 10) {
    CHECK_EQ(robot.step(now).duty, 0);
    if (now % 100 == 0) robot.command(now, 1000, 1);
  }
}

TEST(local_stop_input_latches_through_the_api) {
  Robot robot;
  amz_robot_set_local_stop(robot.r, 1);
  const amz_motion_output out = robot.step(10);
  CHECK(out.status & 0x80);
  CHECK(out.status & 0x01);
  robot.command(20, 0, 0, 0x02);
  CHECK_EQ(amz_robot_e_stop_latched(robot.r), 1);
}

TEST(capi_codec_and_sensor_helpers) {
  amz_command c = {2, 1, 5, 20000, 1, 0, 500};
  uint8_t out[66];
  CHECK_EQ(amz_encode_command(&c, out, sizeof out), -AMZ_ERR_OUT_OF_RANGE);
  c.velocity_mm_s = 100;
  CHECK_EQ(amz_encode_command(&c, out, 10), -AMZ_ERR_BUFFER_TOO_SMALL);
  CHECK_EQ(amz_decode_frame(out, 3, 0), AMZ_ERR_TOO_SHORT);
  CHECK(strcmp(amz_frame_error_name(AMZ_ERR_BAD_ENUM), "bad_enum") == 0);
  CHECK(strcmp(amz_frame_error_name(-1), "unknown") == 0);
  amz_gga_fix fix;
  const char* s = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47";
  CHECK_EQ(amz_parse_gga(s, strlen(s), &fix), 0);
  CHECK_EQ(fix.lat_e7, 481173000L);
  CHECK_EQ(fix.has_position, 1);
  CHECK_EQ(amz_parse_gga("$GPGGA*56", 9, &fix), 5);
  CHECK(amz_robot_create(0, 0, 0, 0) == 0);
}
