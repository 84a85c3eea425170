/* C API of the robot firmware core, for the host simulator (Python ctypes).
 * Built by `make -C firmware shared` as firmware/host/build/libamazing_robot.so.
 * Every struct is plain C with fixed-width fields; no call keeps a pointer it was given.
 * Times are the robot's millis(): u32, wrapping. */
#ifndef AMAZING_ROBOT_H
#define AMAZING_ROBOT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define AMZ_ABI_VERSION 3u

/* Error kinds (docs/protocol.md §3); amz_frame_error_name() gives the shared names. */
enum {
  AMZ_OK = 0,
  AMZ_ERR_TOO_SHORT = 1,
  AMZ_ERR_LENGTH_MISMATCH = 2,
  AMZ_ERR_RESERVED_BITS = 3,
  AMZ_ERR_UNKNOWN_VERSION = 4,
  AMZ_ERR_UNKNOWN_TYPE = 5,
  AMZ_ERR_SIZE_MISMATCH = 6,
  AMZ_ERR_OUT_OF_RANGE = 7,
  AMZ_ERR_BAD_ENUM = 8,
  AMZ_ERR_BUFFER_TOO_SMALL = 9
};

typedef struct amz_robot_config {
  uint8_t node;
  uint8_t base_node;
  uint16_t max_velocity_mm_s;
  uint16_t accel_mm_s2;
  uint16_t stop_decel_mm_s2;
  uint16_t dead_man_ms;
  uint16_t reverse_dwell_ms;
  uint16_t full_scale_mm_s;
  uint8_t duty_min;
  uint8_t duty_max;
  uint16_t hard_max_velocity_mm_s;
  uint16_t accel_min_mm_s2;
  uint16_t accel_max_mm_s2;
  uint16_t battery_vref_mv;
  uint16_t battery_divider_num;
  uint16_t battery_divider_den;
  uint16_t battery_adc_full_scale;
  uint8_t battery_median_window;
  uint16_t low_battery_10mv;
  uint16_t low_battery_hysteresis_10mv;
  uint16_t gps_stale_ms;
  uint16_t wheel_stale_ms;
  char build_id[17]; /* NUL-terminated, at most 16 printable ASCII characters */
} amz_robot_config;

typedef struct amz_motion_output {
  uint8_t duty;          /* 0..255 */
  uint8_t direction;     /* 0 = CCW, 1 = CW */
  uint8_t drive_enabled; /* 0 while the e-stop is latched */
  uint8_t status;        /* telemetry status flags at this step */
  int32_t velocity_mm_s; /* signed applied speed, + = CW */
} amz_motion_output;

typedef struct amz_command {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  uint16_t velocity_mm_s;
  uint8_t direction;
  uint8_t flags;
  uint16_t ttl_ms;
} amz_command;

typedef struct amz_telemetry {
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
} amz_telemetry;

typedef struct amz_config {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  uint16_t max_velocity_mm_s;
  uint16_t accel_mm_s2;
} amz_config;

/* Robot -> BS: the limits applied and the compiled-in hard maximum. */
typedef struct amz_config_ack {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  uint16_t max_velocity_mm_s;
  uint16_t accel_mm_s2;
  uint16_t hard_max_velocity_mm_s;
} amz_config_ack;

/* BS -> robot: asks for the robot's identity. */
typedef struct amz_identify {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
} amz_identify;

/* Robot -> BS: the build identifier and the compiled-in configuration. */
typedef struct amz_identity {
  uint8_t to_node;
  uint8_t from_node;
  uint16_t seq;
  char build_id[17]; /* NUL-terminated */
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
} amz_identity;

typedef struct amz_frame {
  uint8_t type; /* 1 command, 2 telemetry, 3 config, 4 config_ack, 5 identify, 6 identity:
                   the member that is valid */
  amz_command command;
  amz_telemetry telemetry;
  amz_config config;
  amz_config_ack config_ack;
  amz_identify identify;
  amz_identity identity;
} amz_frame;

typedef struct amz_gga_fix {
  uint32_t utc_ms_of_day; /* 0xFFFFFFFF: no time */
  int32_t lat_e7;
  int32_t lon_e7;
  uint8_t quality; /* GGA quality 0..8 */
  uint8_t satellites;
  uint8_t has_position;
} amz_gga_fix;

typedef struct amz_robot amz_robot;

uint32_t amz_abi_version(void);

/* --- the robot: controller, frame handling, sensors --- */
void amz_robot_default_config(amz_robot_config* out);
/* NULL on a NULL config. e_stop_latched: the latch as restored from EEPROM. */
amz_robot* amz_robot_create(const amz_robot_config* config, uint32_t now_ms, int e_stop_latched,
                            int watchdog_reset);
void amz_robot_destroy(amz_robot* robot);
/* A frame as read from the radio FIFO; returns the reply length written (0: no reply). */
size_t amz_robot_handle_frame(amz_robot* robot, uint32_t now_ms, const uint8_t* frame, size_t len,
                              int8_t rssi_dbm, uint8_t* reply, size_t reply_cap);
void amz_robot_step(amz_robot* robot, uint32_t now_ms, amz_motion_output* out);
void amz_robot_add_battery_sample(amz_robot* robot, uint16_t adc_counts);
void amz_robot_feed_gps(amz_robot* robot, uint32_t now_ms, const char* data, size_t len);
void amz_robot_set_local_stop(amz_robot* robot, int open);
void amz_robot_set_measured_velocity(amz_robot* robot, uint32_t now_ms, uint16_t velocity_mm_s);
int amz_robot_e_stop_latched(const amz_robot* robot);
uint8_t amz_robot_status(const amz_robot* robot, uint32_t now_ms);
uint16_t amz_robot_battery_10mv(const amz_robot* robot);

/* --- codec --- */
/* Return the frame length (> 0), or minus an AMZ_ERR_* kind. */
int amz_encode_command(const amz_command* frame, uint8_t* out, size_t cap);
int amz_encode_telemetry(const amz_telemetry* frame, uint8_t* out, size_t cap);
int amz_encode_config(const amz_config* frame, uint8_t* out, size_t cap);
int amz_encode_config_ack(const amz_config_ack* frame, uint8_t* out, size_t cap);
int amz_encode_identify(const amz_identify* frame, uint8_t* out, size_t cap);
int amz_encode_identity(const amz_identity* frame, uint8_t* out, size_t cap);
/* AMZ_OK or an AMZ_ERR_* kind; on AMZ_OK out->type says which member holds the frame. */
int amz_decode_frame(const uint8_t* data, size_t len, amz_frame* out);
const char* amz_frame_error_name(int kind);

/* --- sensors --- */
/* 0 = GGA parsed (out written); otherwise 1 not GGA, 2 no '$', 3 no checksum,
 * 4 bad checksum, 5 malformed, 6 too long. */
int amz_parse_gga(const char* sentence, size_t len, amz_gga_fix* out);
uint16_t amz_battery_counts_to_10mv(uint16_t counts, uint16_t vref_mv, uint16_t divider_num,
                                    uint16_t divider_den, uint16_t adc_full_scale);

#ifdef __cplusplus
}
#endif

#endif
