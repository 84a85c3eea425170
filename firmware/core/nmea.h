// NMEA 0183 GGA parser for the robot's RTK receiver. Integer only: latitude and longitude
// come out as 1e-7 degree integers, exactly as the telemetry frame carries them.
#ifndef AMZ_NMEA_H
#define AMZ_NMEA_H

#include <stddef.h>
#include <stdint.h>

namespace amz {

enum NmeaResult {
  NMEA_OK = 0,            // a GGA sentence, checksum verified, fields valid
  NMEA_NOT_GGA = 1,       // a well-formed sentence of another type (RMC, GSA, ...)
  NMEA_NO_START = 2,      // does not start with '$'
  NMEA_NO_CHECKSUM = 3,   // no "*hh" at the end
  NMEA_BAD_CHECKSUM = 4,  // checksum does not match
  NMEA_MALFORMED = 5,     // a GGA whose fields do not parse
  NMEA_TOO_LONG = 6       // longer than the reader's buffer
};

// GGA quality indicator (field 6).
enum GgaQuality {
  GGA_INVALID = 0,
  GGA_GPS = 1,
  GGA_DGPS = 2,
  GGA_PPS = 3,
  GGA_RTK_FIXED = 4,
  GGA_RTK_FLOAT = 5,
  GGA_ESTIMATED = 6,
  GGA_MANUAL = 7,
  GGA_SIMULATION = 8
};

const uint32_t kNoUtcTime = 0xFFFFFFFFUL;

struct GgaFix {
  uint32_t utc_ms_of_day;  // kNoUtcTime when the time field is empty
  int32_t lat_e7;          // 1e-7 degree, south negative (0 without position)
  int32_t lon_e7;          // 1e-7 degree, west negative (0 without position)
  uint8_t quality;         // GgaQuality
  uint8_t satellites;      // satellites in use
  bool has_position;       // latitude and longitude fields were present
};

// Parse one sentence, '$' to checksum, a trailing "\r\n" allowed. `out` is written only on
// NMEA_OK. Digits of the minutes beyond the seventh decimal are ignored.
NmeaResult parse_gga(const char* sentence, size_t len, GgaFix* out);

// The wire's fix quality for a GGA quality: 1, 2, 4 and 5 pass through, anything else
// (no fix, PPS, dead reckoning, manual, simulation) is "no fix".
uint8_t wire_fix_quality(uint8_t gga_quality);

// Assembles sentences from a byte stream (a UART): starts at '$', ends at '\n'.
class NmeaReader {
 public:
  static const uint8_t kCapacity = 100;  // NMEA says 82; RTK receivers print more digits

  NmeaReader() : len_(0), state_(kIdle) {}
  void reset() {
    len_ = 0;
    state_ = kIdle;
  }
  // Feed one byte; returns true when a sentence ended and *result holds its outcome
  // (*fix is written on NMEA_OK only).
  bool feed(char c, NmeaResult* result, GgaFix* fix);

 private:
  enum State { kIdle, kInSentence, kOverflow };
  char buf_[kCapacity];
  uint8_t len_;
  uint8_t state_;
};

}  // namespace amz

#endif
