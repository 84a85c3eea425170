// The C++ codec against tests/vectors/protocol.json (one case per vector) and more.
#include <string.h>

#include "harness.h"
#include "protocol.h"
#include "vectors.h"

using namespace amz;

namespace {

bool same_command(const CommandFrame& a, const CommandFrame& b) {
  return a.to_node == b.to_node && a.from_node == b.from_node && a.seq == b.seq &&
         a.velocity_mm_s == b.velocity_mm_s && a.direction == b.direction &&
         a.flags == b.flags && a.ttl_ms == b.ttl_ms;
}

bool same_telemetry(const TelemetryFrame& a, const TelemetryFrame& b) {
  return a.to_node == b.to_node && a.from_node == b.from_node && a.seq == b.seq &&
         a.echo_seq == b.echo_seq && a.robot_clock_ms == b.robot_clock_ms &&
         a.velocity_mm_s == b.velocity_mm_s && a.direction == b.direction &&
         a.battery_10mv == b.battery_10mv && a.lat_e7 == b.lat_e7 && a.lon_e7 == b.lon_e7 &&
         a.fix_quality == b.fix_quality && a.satellites == b.satellites &&
         a.status == b.status && a.rssi_dbm == b.rssi_dbm;
}

bool same_config(const ConfigFrame& a, const ConfigFrame& b) {
  return a.to_node == b.to_node && a.from_node == b.from_node && a.seq == b.seq &&
         a.max_velocity_mm_s == b.max_velocity_mm_s && a.accel_mm_s2 == b.accel_mm_s2;
}

bool same_config_ack(const ConfigAckFrame& a, const ConfigAckFrame& b) {
  return a.to_node == b.to_node && a.from_node == b.from_node && a.seq == b.seq &&
         a.max_velocity_mm_s == b.max_velocity_mm_s && a.accel_mm_s2 == b.accel_mm_s2 &&
         a.hard_max_velocity_mm_s == b.hard_max_velocity_mm_s;
}

bool same_identify(const IdentifyFrame& a, const IdentifyFrame& b) {
  return a.to_node == b.to_node && a.from_node == b.from_node && a.seq == b.seq;
}

bool same_identity(const IdentityFrame& a, const IdentityFrame& b) {
  return a.to_node == b.to_node && a.from_node == b.from_node && a.seq == b.seq &&
         strcmp(a.build_id, b.build_id) == 0 &&
         a.hard_max_velocity_mm_s == b.hard_max_velocity_mm_s &&
         a.max_velocity_mm_s == b.max_velocity_mm_s && a.accel_mm_s2 == b.accel_mm_s2 &&
         a.accel_min_mm_s2 == b.accel_min_mm_s2 && a.accel_max_mm_s2 == b.accel_max_mm_s2 &&
         a.stop_decel_mm_s2 == b.stop_decel_mm_s2 && a.dead_man_ms == b.dead_man_ms &&
         a.reverse_dwell_ms == b.reverse_dwell_ms && a.full_scale_mm_s == b.full_scale_mm_s &&
         a.low_battery_10mv == b.low_battery_10mv && a.gps_stale_ms == b.gps_stale_ms &&
         a.battery_median_window == b.battery_median_window;
}

bool same_frame(const Frame& a, const Frame& b) {
  if (a.type != b.type) return false;
  switch (a.type) {
    case FRAME_COMMAND:
      return same_command(a.command, b.command);
    case FRAME_TELEMETRY:
      return same_telemetry(a.telemetry, b.telemetry);
    case FRAME_CONFIG:
      return same_config(a.config, b.config);
    case FRAME_CONFIG_ACK:
      return same_config_ack(a.config_ack, b.config_ack);
    case FRAME_IDENTIFY:
      return same_identify(a.identify, b.identify);
    case FRAME_IDENTITY:
      return same_identity(a.identity, b.identity);
    default:
      return false;
  }
}

void run_valid(void* context) {
  const vectors::Valid& v = *static_cast<const vectors::Valid*>(context);
  Frame expected;
  memset(&expected, 0, sizeof expected);
  v.fill(&expected);

  Frame decoded;
  memset(&decoded, 0, sizeof decoded);
  CHECK_EQ(decode_frame(v.bytes, v.len, &decoded), FRAME_OK);
  CHECK_MSG(same_frame(decoded, expected), "decoded fields differ from the vector's fields");

  uint8_t out[kMaxFrameSize];
  size_t written = 0;
  CHECK_EQ(encode_frame(expected, out, sizeof out, &written), FRAME_OK);
  CHECK_EQ(written, v.len);
  CHECK_MSG(written == v.len && memcmp(out, v.bytes, v.len) == 0,
            "encoded bytes differ from the vector's bytes");
  // One byte of room too few: nothing but an error.
  CHECK_EQ(encode_frame(expected, out, v.len - 1, &written), ERR_BUFFER_TOO_SMALL);
}

void run_malformed(void* context) {
  const vectors::Malformed& v = *static_cast<const vectors::Malformed*>(context);
  Frame decoded;
  const FrameError error = decode_frame(v.bytes, v.len, &decoded);
  CHECK_MSG(strcmp(frame_error_name(error), v.error) == 0, frame_error_name(error));
}

// One name per vector, however many the file holds (+1: an array may not be empty).
char g_names[vectors::kValidCount + vectors::kMalformedCount + 1][96];

}  // namespace

void register_vector_tests() {
  size_t n = 0;
  for (size_t i = 0; i < vectors::kValidCount; ++i, ++n) {
    snprintf(g_names[n], sizeof g_names[n], "vector_valid_%s", vectors::kValid[i].name);
    harness::register_test(g_names[n], &run_valid,
                           const_cast<vectors::Valid*>(&vectors::kValid[i]));
  }
  for (size_t i = 0; i < vectors::kMalformedCount; ++i, ++n) {
    snprintf(g_names[n], sizeof g_names[n], "vector_malformed_%s", vectors::kMalformed[i].name);
    harness::register_test(g_names[n], &run_malformed,
                           const_cast<vectors::Malformed*>(&vectors::kMalformed[i]));
  }
}

TEST(vector_file_covers_every_error_kind) {
  const char* kinds[] = {"too_short",    "length_mismatch", "reserved_bits", "unknown_version",
                         "unknown_type", "size_mismatch",   "out_of_range",  "bad_enum"};
  for (size_t k = 0; k < sizeof kinds / sizeof kinds[0]; ++k) {
    bool found = false;
    for (size_t i = 0; i < vectors::kMalformedCount; ++i) {
      if (strcmp(vectors::kMalformed[i].error, kinds[k]) == 0) found = true;
    }
    CHECK_MSG(found, kinds[k]);
  }
}

TEST(seq_newer_uses_serial_number_arithmetic) {
  CHECK(seq_newer(1, 2));
  CHECK(!seq_newer(2, 2));
  CHECK(!seq_newer(3, 2));
  CHECK(seq_newer(65535, 0));
  CHECK(seq_newer(65000, 100));
  CHECK(!seq_newer(100, 65000));
}

TEST(encoder_refuses_fields_the_decoder_would_reject) {
  uint8_t out[kMaxFrameSize];
  size_t written = 0;
  CommandFrame c = {2, 1, 1, 10001, DIR_CW, 0, 500};
  CHECK_EQ(encode_command(c, out, sizeof out, &written), ERR_OUT_OF_RANGE);
  c.velocity_mm_s = 100;
  c.direction = 2;
  CHECK_EQ(encode_command(c, out, sizeof out, &written), ERR_BAD_ENUM);
  c.direction = DIR_CCW;
  c.flags = 0x10;
  CHECK_EQ(encode_command(c, out, sizeof out, &written), ERR_RESERVED_BITS);
  ConfigFrame k = {2, 1, 5, 1000, 0};
  CHECK_EQ(encode_config(k, out, sizeof out, &written), ERR_OUT_OF_RANGE);
  ConfigAckFrame a = {1, 2, 5, 1000, 250, 10001};
  CHECK_EQ(encode_config_ack(a, out, sizeof out, &written), ERR_OUT_OF_RANGE);
  TelemetryFrame t;
  memset(&t, 0, sizeof t);
  t.fix_quality = 3;
  CHECK_EQ(encode_telemetry(t, out, sizeof out, &written), ERR_BAD_ENUM);
  t.fix_quality = 0;
  t.lat_e7 = 900000001L;
  CHECK_EQ(encode_telemetry(t, out, sizeof out, &written), ERR_OUT_OF_RANGE);
  IdentityFrame y;
  memset(&y, 0, sizeof y);
  y.accel_mm_s2 = y.accel_min_mm_s2 = y.accel_max_mm_s2 = 100;
  strcpy(y.build_id, "v1.2");
  CHECK_EQ(encode_identity(y, out, sizeof out, &written), FRAME_OK);
  CHECK_EQ(written, kIdentityFrameSize);
  y.build_id[1] = '\n';  // not printable
  CHECK_EQ(encode_identity(y, out, sizeof out, &written), ERR_OUT_OF_RANGE);
  memset(y.build_id, 'x', sizeof y.build_id);  // 17 characters, no room for the end
  CHECK_EQ(encode_identity(y, out, sizeof out, &written), ERR_OUT_OF_RANGE);
  strcpy(y.build_id, "v1.2");
  y.hard_max_velocity_mm_s = 10001;
  CHECK_EQ(encode_identity(y, out, sizeof out, &written), ERR_OUT_OF_RANGE);
  y.hard_max_velocity_mm_s = 4000;
  y.accel_min_mm_s2 = 0;
  CHECK_EQ(encode_identity(y, out, sizeof out, &written), ERR_OUT_OF_RANGE);
}

TEST(decoder_survives_arbitrary_bytes) {
  // Deterministic pseudo-random bytes (LCG); each accepted frame must re-encode to itself.
  uint32_t state = 12345;
  uint8_t buf[80];
  Frame f;
  int accepted = 0;
  for (int round = 0; round < 200000; ++round) {
    state = state * 1664525UL + 1013904223UL;
    const size_t len = (state >> 24) % sizeof buf;
    for (size_t i = 0; i < len; ++i) {
      state = state * 1664525UL + 1013904223UL;
      buf[i] = static_cast<uint8_t>(state >> 24);
    }
    // Make a good share of the inputs get past the header checks.
    if (len > 0 && (round & 1)) buf[0] = static_cast<uint8_t>(len - 1);
    if (len > 5 && (round & 2)) {
      buf[3] = 0;
      buf[4] = 1;
      buf[5] = static_cast<uint8_t>(1 + (round >> 2) % 6);
    }
    const FrameError e = decode_frame(buf, len, &f);
    CHECK(e <= ERR_BAD_ENUM);
    if (e == FRAME_OK) {
      ++accepted;
      uint8_t out[kMaxFrameSize];
      size_t written = 0;
      CHECK_EQ(encode_frame(f, out, sizeof out, &written), FRAME_OK);
      CHECK(written == len && memcmp(out, buf, len) == 0);
    }
  }
  CHECK(accepted > 0);
}

TEST(decoder_rejects_null_and_empty_input) {
  Frame f;
  CHECK_EQ(decode_frame(0, 14, &f), ERR_TOO_SHORT);
  const uint8_t one = 0;
  CHECK_EQ(decode_frame(&one, 0, &f), ERR_TOO_SHORT);
}
