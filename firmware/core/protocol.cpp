#include "protocol.h"

namespace amz {
namespace {

uint16_t get_u16(const uint8_t* p) {
  return static_cast<uint16_t>(p[0] | (static_cast<uint16_t>(p[1]) << 8));
}

uint32_t get_u32(const uint8_t* p) {
  return static_cast<uint32_t>(p[0]) | (static_cast<uint32_t>(p[1]) << 8) |
         (static_cast<uint32_t>(p[2]) << 16) | (static_cast<uint32_t>(p[3]) << 24);
}

void put_u16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
}

void put_u32(uint8_t* p, uint32_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
  p[2] = static_cast<uint8_t>(v >> 16);
  p[3] = static_cast<uint8_t>(v >> 24);
}

FrameError check_velocity(uint16_t velocity_mm_s) {
  return velocity_mm_s <= kVelocityLimitMmS ? FRAME_OK : ERR_OUT_OF_RANGE;
}

FrameError check_direction(uint8_t direction) {
  return direction == DIR_CCW || direction == DIR_CW ? FRAME_OK : ERR_BAD_ENUM;
}

FrameError check_command_flags(uint8_t flags) {
  return (flags & ~kCommandFlagsDefined) == 0 ? FRAME_OK : ERR_RESERVED_BITS;
}

FrameError check_lat_lon(int32_t lat_e7, int32_t lon_e7) {
  if (lat_e7 < -kLatLimitE7 || lat_e7 > kLatLimitE7) return ERR_OUT_OF_RANGE;
  if (lon_e7 < -kLonLimitE7 || lon_e7 > kLonLimitE7) return ERR_OUT_OF_RANGE;
  return FRAME_OK;
}

FrameError check_fix_quality(uint8_t q) {
  return q == FIX_NONE || q == FIX_GPS || q == FIX_DGPS || q == FIX_RTK_FIXED ||
                 q == FIX_RTK_FLOAT
             ? FRAME_OK
             : ERR_BAD_ENUM;
}

FrameError check_accel(uint16_t accel_mm_s2) {
  return accel_mm_s2 >= 1 && accel_mm_s2 <= kAccelLimitMmS2 ? FRAME_OK : ERR_OUT_OF_RANGE;
}

FrameError check_command(const CommandFrame& f) {
  FrameError e = check_velocity(f.velocity_mm_s);
  if (e == FRAME_OK) e = check_direction(f.direction);
  if (e == FRAME_OK) e = check_command_flags(f.flags);
  return e;
}

FrameError check_telemetry(const TelemetryFrame& f) {
  FrameError e = check_direction(f.direction);
  if (e == FRAME_OK) e = check_lat_lon(f.lat_e7, f.lon_e7);
  if (e == FRAME_OK) e = check_fix_quality(f.fix_quality);
  return e;
}

FrameError check_config(const ConfigFrame& f) {
  FrameError e = check_velocity(f.max_velocity_mm_s);
  if (e == FRAME_OK) e = check_accel(f.accel_mm_s2);
  return e;
}

FrameError check_config_ack(const ConfigAckFrame& f) {
  FrameError e = check_velocity(f.max_velocity_mm_s);
  if (e == FRAME_OK) e = check_accel(f.accel_mm_s2);
  if (e == FRAME_OK) e = check_velocity(f.hard_max_velocity_mm_s);
  return e;
}

// Printable ASCII up to the first NUL, then only NULs: one spelling per identifier, so a
// decoded frame encodes back to the same bytes.
FrameError check_wire_build_id(const uint8_t* p) {
  bool ended = false;
  for (uint8_t i = 0; i < kBuildIdSize; ++i) {
    if (p[i] == 0) {
      ended = true;
    } else if (ended || p[i] < 0x20 || p[i] > 0x7e) {
      return ERR_OUT_OF_RANGE;
    }
  }
  return FRAME_OK;
}

FrameError check_build_id(const char* id) {
  for (uint8_t i = 0; i <= kBuildIdSize; ++i) {
    const uint8_t c = static_cast<uint8_t>(id[i]);
    if (c == 0) return FRAME_OK;
    if (i == kBuildIdSize || c < 0x20 || c > 0x7e) return ERR_OUT_OF_RANGE;
  }
  return ERR_OUT_OF_RANGE;
}

FrameError check_identity_numbers(const IdentityFrame& f) {
  FrameError e = check_velocity(f.hard_max_velocity_mm_s);
  if (e == FRAME_OK) e = check_velocity(f.max_velocity_mm_s);
  if (e == FRAME_OK) e = check_accel(f.accel_mm_s2);
  if (e == FRAME_OK) e = check_accel(f.accel_min_mm_s2);
  if (e == FRAME_OK) e = check_accel(f.accel_max_mm_s2);
  return e;
}

uint8_t frame_size(uint8_t type) {
  switch (type) {
    case FRAME_COMMAND:
      return kCommandFrameSize;
    case FRAME_TELEMETRY:
      return kTelemetryFrameSize;
    case FRAME_CONFIG:
      return kConfigFrameSize;
    case FRAME_CONFIG_ACK:
      return kConfigAckFrameSize;
    case FRAME_IDENTIFY:
      return kIdentifyFrameSize;
    case FRAME_IDENTITY:
      return kIdentityFrameSize;
    default:
      return 0;
  }
}

void put_header(uint8_t* out, uint8_t type, uint8_t to_node, uint8_t from_node) {
  out[0] = static_cast<uint8_t>(frame_size(type) - 1);
  out[1] = to_node;
  out[2] = from_node;
  out[3] = 0;
  out[4] = kProtocolVersion;
  out[5] = type;
}

}  // namespace

FrameError decode_frame(const uint8_t* data, size_t len, Frame* out) {
  if (data == 0 || len < kHeaderSize) return ERR_TOO_SHORT;
  if (static_cast<size_t>(data[0]) != len - 1) return ERR_LENGTH_MISMATCH;
  if (data[3] != 0) return ERR_RESERVED_BITS;
  if (data[4] != kProtocolVersion) return ERR_UNKNOWN_VERSION;
  const uint8_t type = data[5];
  const uint8_t expected = frame_size(type);
  if (expected == 0) return ERR_UNKNOWN_TYPE;
  if (len != expected) return ERR_SIZE_MISMATCH;

  Frame f;
  f.type = type;
  const uint8_t* p = data + kHeaderSize;
  FrameError e = FRAME_OK;
  if (type == FRAME_COMMAND) {
    CommandFrame& c = f.command;
    c.to_node = data[1];
    c.from_node = data[2];
    c.seq = get_u16(p);
    c.velocity_mm_s = get_u16(p + 2);
    c.direction = p[4];
    c.flags = p[5];
    c.ttl_ms = get_u16(p + 6);
    e = check_command(c);
  } else if (type == FRAME_TELEMETRY) {
    TelemetryFrame& t = f.telemetry;
    t.to_node = data[1];
    t.from_node = data[2];
    t.seq = get_u16(p);
    t.echo_seq = get_u16(p + 2);
    t.robot_clock_ms = get_u32(p + 4);
    t.velocity_mm_s = get_u16(p + 8);
    t.direction = p[10];
    t.battery_10mv = get_u16(p + 11);
    t.lat_e7 = static_cast<int32_t>(get_u32(p + 13));
    t.lon_e7 = static_cast<int32_t>(get_u32(p + 17));
    t.fix_quality = p[21];
    t.satellites = p[22];
    t.status = p[23];
    t.rssi_dbm = static_cast<int8_t>(p[24]);
    e = check_telemetry(t);
  } else if (type == FRAME_IDENTIFY) {
    IdentifyFrame& q = f.identify;
    q.to_node = data[1];
    q.from_node = data[2];
    q.seq = get_u16(p);
  } else if (type == FRAME_IDENTITY) {
    IdentityFrame& y = f.identity;
    y.to_node = data[1];
    y.from_node = data[2];
    y.seq = get_u16(p);
    e = check_wire_build_id(p + 2);
    for (uint8_t i = 0; i < kBuildIdSize; ++i) y.build_id[i] = static_cast<char>(p[2 + i]);
    y.build_id[kBuildIdSize] = 0;
    const uint8_t* n = p + 2 + kBuildIdSize;
    y.hard_max_velocity_mm_s = get_u16(n);
    y.max_velocity_mm_s = get_u16(n + 2);
    y.accel_mm_s2 = get_u16(n + 4);
    y.accel_min_mm_s2 = get_u16(n + 6);
    y.accel_max_mm_s2 = get_u16(n + 8);
    y.stop_decel_mm_s2 = get_u16(n + 10);
    y.dead_man_ms = get_u16(n + 12);
    y.reverse_dwell_ms = get_u16(n + 14);
    y.full_scale_mm_s = get_u16(n + 16);
    y.low_battery_10mv = get_u16(n + 18);
    y.gps_stale_ms = get_u16(n + 20);
    y.battery_median_window = n[22];
    if (e == FRAME_OK) e = check_identity_numbers(y);
  } else if (type == FRAME_CONFIG_ACK) {
    ConfigAckFrame& a = f.config_ack;
    a.to_node = data[1];
    a.from_node = data[2];
    a.seq = get_u16(p);
    a.max_velocity_mm_s = get_u16(p + 2);
    a.accel_mm_s2 = get_u16(p + 4);
    a.hard_max_velocity_mm_s = get_u16(p + 6);
    e = check_config_ack(a);
  } else {
    ConfigFrame& c = f.config;
    c.to_node = data[1];
    c.from_node = data[2];
    c.seq = get_u16(p);
    c.max_velocity_mm_s = get_u16(p + 2);
    c.accel_mm_s2 = get_u16(p + 4);
    e = check_config(c);
  }
  if (e == FRAME_OK && out != 0) *out = f;
  return e;
}

FrameError encode_command(const CommandFrame& f, uint8_t* out, size_t cap, size_t* written) {
  const FrameError e = check_command(f);
  if (e != FRAME_OK) return e;
  if (out == 0 || cap < kCommandFrameSize) return ERR_BUFFER_TOO_SMALL;
  put_header(out, FRAME_COMMAND, f.to_node, f.from_node);
  uint8_t* p = out + kHeaderSize;
  put_u16(p, f.seq);
  put_u16(p + 2, f.velocity_mm_s);
  p[4] = f.direction;
  p[5] = f.flags;
  put_u16(p + 6, f.ttl_ms);
  if (written != 0) *written = kCommandFrameSize;
  return FRAME_OK;
}

FrameError encode_telemetry(const TelemetryFrame& f, uint8_t* out, size_t cap,
                            size_t* written) {
  const FrameError e = check_telemetry(f);
  if (e != FRAME_OK) return e;
  if (out == 0 || cap < kTelemetryFrameSize) return ERR_BUFFER_TOO_SMALL;
  put_header(out, FRAME_TELEMETRY, f.to_node, f.from_node);
  uint8_t* p = out + kHeaderSize;
  put_u16(p, f.seq);
  put_u16(p + 2, f.echo_seq);
  put_u32(p + 4, f.robot_clock_ms);
  put_u16(p + 8, f.velocity_mm_s);
  p[10] = f.direction;
  put_u16(p + 11, f.battery_10mv);
  put_u32(p + 13, static_cast<uint32_t>(f.lat_e7));
  put_u32(p + 17, static_cast<uint32_t>(f.lon_e7));
  p[21] = f.fix_quality;
  p[22] = f.satellites;
  p[23] = f.status;
  p[24] = static_cast<uint8_t>(f.rssi_dbm);
  if (written != 0) *written = kTelemetryFrameSize;
  return FRAME_OK;
}

FrameError encode_config(const ConfigFrame& f, uint8_t* out, size_t cap, size_t* written) {
  const FrameError e = check_config(f);
  if (e != FRAME_OK) return e;
  if (out == 0 || cap < kConfigFrameSize) return ERR_BUFFER_TOO_SMALL;
  put_header(out, FRAME_CONFIG, f.to_node, f.from_node);
  uint8_t* p = out + kHeaderSize;
  put_u16(p, f.seq);
  put_u16(p + 2, f.max_velocity_mm_s);
  put_u16(p + 4, f.accel_mm_s2);
  if (written != 0) *written = kConfigFrameSize;
  return FRAME_OK;
}

FrameError encode_config_ack(const ConfigAckFrame& f, uint8_t* out, size_t cap,
                             size_t* written) {
  const FrameError e = check_config_ack(f);
  if (e != FRAME_OK) return e;
  if (out == 0 || cap < kConfigAckFrameSize) return ERR_BUFFER_TOO_SMALL;
  put_header(out, FRAME_CONFIG_ACK, f.to_node, f.from_node);
  uint8_t* p = out + kHeaderSize;
  put_u16(p, f.seq);
  put_u16(p + 2, f.max_velocity_mm_s);
  put_u16(p + 4, f.accel_mm_s2);
  put_u16(p + 6, f.hard_max_velocity_mm_s);
  if (written != 0) *written = kConfigAckFrameSize;
  return FRAME_OK;
}

FrameError encode_identify(const IdentifyFrame& f, uint8_t* out, size_t cap,
                           size_t* written) {
  if (out == 0 || cap < kIdentifyFrameSize) return ERR_BUFFER_TOO_SMALL;
  put_header(out, FRAME_IDENTIFY, f.to_node, f.from_node);
  put_u16(out + kHeaderSize, f.seq);
  if (written != 0) *written = kIdentifyFrameSize;
  return FRAME_OK;
}

FrameError encode_identity(const IdentityFrame& f, uint8_t* out, size_t cap,
                           size_t* written) {
  FrameError e = check_build_id(f.build_id);
  if (e == FRAME_OK) e = check_identity_numbers(f);
  if (e != FRAME_OK) return e;
  if (out == 0 || cap < kIdentityFrameSize) return ERR_BUFFER_TOO_SMALL;
  put_header(out, FRAME_IDENTITY, f.to_node, f.from_node);
  uint8_t* p = out + kHeaderSize;
  put_u16(p, f.seq);
  bool ended = false;
  for (uint8_t i = 0; i < kBuildIdSize; ++i) {
    if (f.build_id[i] == 0) ended = true;
    p[2 + i] = ended ? 0 : static_cast<uint8_t>(f.build_id[i]);
  }
  uint8_t* n = p + 2 + kBuildIdSize;
  put_u16(n, f.hard_max_velocity_mm_s);
  put_u16(n + 2, f.max_velocity_mm_s);
  put_u16(n + 4, f.accel_mm_s2);
  put_u16(n + 6, f.accel_min_mm_s2);
  put_u16(n + 8, f.accel_max_mm_s2);
  put_u16(n + 10, f.stop_decel_mm_s2);
  put_u16(n + 12, f.dead_man_ms);
  put_u16(n + 14, f.reverse_dwell_ms);
  put_u16(n + 16, f.full_scale_mm_s);
  put_u16(n + 18, f.low_battery_10mv);
  put_u16(n + 20, f.gps_stale_ms);
  n[22] = f.battery_median_window;
  if (written != 0) *written = kIdentityFrameSize;
  return FRAME_OK;
}

FrameError encode_frame(const Frame& f, uint8_t* out, size_t cap, size_t* written) {
  switch (f.type) {
    case FRAME_COMMAND:
      return encode_command(f.command, out, cap, written);
    case FRAME_TELEMETRY:
      return encode_telemetry(f.telemetry, out, cap, written);
    case FRAME_CONFIG:
      return encode_config(f.config, out, cap, written);
    case FRAME_CONFIG_ACK:
      return encode_config_ack(f.config_ack, out, cap, written);
    case FRAME_IDENTIFY:
      return encode_identify(f.identify, out, cap, written);
    case FRAME_IDENTITY:
      return encode_identity(f.identity, out, cap, written);
    default:
      return ERR_UNKNOWN_TYPE;
  }
}

const char* frame_error_name(uint8_t error) {
  switch (error) {
    case FRAME_OK:
      return "ok";
    case ERR_TOO_SHORT:
      return "too_short";
    case ERR_LENGTH_MISMATCH:
      return "length_mismatch";
    case ERR_RESERVED_BITS:
      return "reserved_bits";
    case ERR_UNKNOWN_VERSION:
      return "unknown_version";
    case ERR_UNKNOWN_TYPE:
      return "unknown_type";
    case ERR_SIZE_MISMATCH:
      return "size_mismatch";
    case ERR_OUT_OF_RANGE:
      return "out_of_range";
    case ERR_BAD_ENUM:
      return "bad_enum";
    case ERR_BUFFER_TOO_SMALL:
      return "buffer_too_small";
    default:
      return "unknown";
  }
}

}  // namespace amz
