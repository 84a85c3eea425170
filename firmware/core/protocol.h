// Wire protocol of docs/protocol.md, version 1: frames between base station and robot.
// Portable C++11: no Arduino headers, no allocation, no exceptions.
#ifndef AMZ_PROTOCOL_H
#define AMZ_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

namespace amz {

const uint8_t kProtocolVersion = 1;
const uint8_t kHeaderSize = 6;
const uint8_t kCommandFrameSize = 14;
const uint8_t kTelemetryFrameSize = 31;
const uint8_t kConfigFrameSize = 12;
const uint8_t kConfigAckFrameSize = 14;
const uint8_t kIdentifyFrameSize = 8;
const uint8_t kIdentityFrameSize = 47;
// The build identifier on the wire: printable ASCII, NUL-padded to this many bytes.
const uint8_t kBuildIdSize = 16;
const uint8_t kMaxFrameSize = 66;  // the RFM69 FIFO

const uint16_t kVelocityLimitMmS = 10000;  // wire limit; the robot clamps further
const uint16_t kAccelLimitMmS2 = 10000;
const int32_t kLatLimitE7 = 900000000L;
const int32_t kLonLimitE7 = 1800000000L;

const uint8_t kBroadcastNode = 255;

enum FrameType {
  FRAME_COMMAND = 1,
  FRAME_TELEMETRY = 2,
  FRAME_CONFIG = 3,
  FRAME_CONFIG_ACK = 4,
  FRAME_IDENTIFY = 5,
  FRAME_IDENTITY = 6
};

enum Direction { DIR_CCW = 0, DIR_CW = 1 };

enum FixQuality {
  FIX_NONE = 0,
  FIX_GPS = 1,
  FIX_DGPS = 2,
  FIX_RTK_FIXED = 4,
  FIX_RTK_FLOAT = 5
};

enum CommandFlag { CMD_E_STOP = 0x01, CMD_E_STOP_RELEASE = 0x02 };
const uint8_t kCommandFlagsDefined = 0x03;

enum StatusFlag {
  ST_E_STOP_LATCHED = 0x01,
  ST_DEAD_MAN = 0x02,
  ST_TTL_EXPIRED = 0x04,
  ST_CLAMPED = 0x08,
  ST_LOW_BATTERY = 0x10,
  ST_GPS_STALE = 0x20,
  ST_WATCHDOG_RESET = 0x40,
  ST_LOCAL_STOP = 0x80
};

// Reject kinds in the order a decoder checks them (docs/protocol.md §3). The names are
// the ones of the Python FrameError.kind and of tests/vectors/protocol.json.
enum FrameError {
  FRAME_OK = 0,
  ERR_TOO_SHORT = 1,
  ERR_LENGTH_MISMATCH = 2,
  ERR_RESERVED_BITS = 3,
  ERR_UNKNOWN_VERSION = 4,
  ERR_UNKNOWN_TYPE = 5,
  ERR_SIZE_MISMATCH = 6,
  ERR_OUT_OF_RANGE = 7,
  ERR_BAD_ENUM = 8,
  ERR_BUFFER_TOO_SMALL = 9  // encoder only: the output buffer cannot hold the frame
};

struct CommandFrame {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  uint16_t velocity_mm_s;
  uint8_t direction;
  uint8_t flags;
  uint16_t ttl_ms;
};

struct TelemetryFrame {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  uint16_t echo_seq;
  uint32_t robot_clock_ms;
  uint16_t velocity_mm_s;
  uint8_t direction;
  uint16_t battery_10mv;
  int32_t lat_e7;
  int32_t lon_e7;
  uint8_t fix_quality;
  uint8_t satellites;
  uint8_t status;
  int8_t rssi_dbm;
};

struct ConfigFrame {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  uint16_t max_velocity_mm_s;
  uint16_t accel_mm_s2;
};

// Robot -> BS: the answer to a config frame, with the compiled-in hard maximum.
struct ConfigAckFrame {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  uint16_t max_velocity_mm_s;
  uint16_t accel_mm_s2;
  uint16_t hard_max_velocity_mm_s;
};

// BS -> robot: "which firmware are you, built how?" (docs/protocol.md §2.5).
struct IdentifyFrame {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
};

// Robot -> BS: the build identifier and the compiled-in configuration (§2.6).
struct IdentityFrame {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  char build_id[kBuildIdSize + 1];  // NUL-terminated; printable ASCII
  uint16_t hard_max_velocity_mm_s;
  uint16_t max_velocity_mm_s;
  uint16_t accel_mm_s2;
  uint16_t accel_min_mm_s2;
  uint16_t accel_max_mm_s2;
  uint16_t stop_decel_mm_s2;
  uint16_t dead_man_ms;
  uint16_t reverse_dwell_ms;
  uint16_t full_scale_mm_s;
  uint16_t low_battery_10mv;
  uint16_t gps_stale_ms;
  uint8_t battery_median_window;
};

struct Frame {
  uint8_t type;  // FrameType; selects the member of the union
  union {
    CommandFrame command;
    TelemetryFrame telemetry;
    ConfigFrame config;
    ConfigAckFrame config_ack;
    IdentifyFrame identify;
    IdentityFrame identity;
  };
};

// Decode one frame (length byte first, as read from the FIFO). On FRAME_OK `out` holds it.
FrameError decode_frame(const uint8_t* data, size_t len, Frame* out);

// Encode into `out` (capacity `cap`); on FRAME_OK `*written` is the frame length. A field
// that the decoder would reject gives that decoder's error and writes nothing.
FrameError encode_command(const CommandFrame& frame, uint8_t* out, size_t cap, size_t* written);
FrameError encode_telemetry(const TelemetryFrame& frame, uint8_t* out, size_t cap,
                            size_t* written);
FrameError encode_config(const ConfigFrame& frame, uint8_t* out, size_t cap, size_t* written);
FrameError encode_config_ack(const ConfigAckFrame& frame, uint8_t* out, size_t cap,
                             size_t* written);
FrameError encode_identify(const IdentifyFrame& frame, uint8_t* out, size_t cap,
                           size_t* written);
FrameError encode_identity(const IdentityFrame& frame, uint8_t* out, size_t cap,
                           size_t* written);
FrameError encode_frame(const Frame& frame, uint8_t* out, size_t cap, size_t* written);

// "too_short", "length_mismatch", ...; "unknown" for a value outside the enum.
const char* frame_error_name(uint8_t error);

// Serial-number arithmetic on u16 sequence numbers: is `candidate` newer than `last`?
inline bool seq_newer(uint16_t last, uint16_t candidate) {
  return static_cast<int16_t>(static_cast<uint16_t>(candidate - last)) > 0;
}

}  // namespace amz

#endif
