#include "nmea.h"

namespace amz {
namespace {

const uint8_t kGgaFields = 14;  // after the address field

bool is_digit(char c) { return c >= '0' && c <= '9'; }

int8_t hex_value(char c) {
  if (c >= '0' && c <= '9') return static_cast<int8_t>(c - '0');
  if (c >= 'A' && c <= 'F') return static_cast<int8_t>(c - 'A' + 10);
  if (c >= 'a' && c <= 'f') return static_cast<int8_t>(c - 'a' + 10);
  return -1;
}

struct Field {
  const char* p;
  uint8_t len;
};

// Exactly `n` digits at p -> value.
bool fixed_digits(const char* p, uint8_t n, uint32_t* value) {
  uint32_t v = 0;
  for (uint8_t i = 0; i < n; ++i) {
    if (!is_digit(p[i])) return false;
    v = v * 10 + static_cast<uint32_t>(p[i] - '0');
  }
  *value = v;
  return true;
}

// An unsigned decimal of 1..max_digits digits, nothing else.
bool uint_field(const Field& f, uint8_t max_digits, uint32_t* value) {
  if (f.len == 0 || f.len > max_digits) return false;
  return fixed_digits(f.p, f.len, value);
}

// Optional sign, digits, optional '.' and digits; at least one digit. Value not needed.
bool decimal_field(const Field& f) {
  uint8_t i = 0;
  if (f.len > 0 && (f.p[0] == '-' || f.p[0] == '+')) i = 1;
  bool digits = false;
  bool dot = false;
  for (; i < f.len; ++i) {
    if (is_digit(f.p[i])) {
      digits = true;
    } else if (f.p[i] == '.' && !dot) {
      dot = true;
    } else {
      return false;
    }
  }
  return digits;
}

bool empty_or_decimal(const Field& f) { return f.len == 0 || decimal_field(f); }

bool empty_or_unit_m(const Field& f) { return f.len == 0 || (f.len == 1 && f.p[0] == 'M'); }

// hhmmss[.s...] -> ms of the day.
bool time_field(const Field& f, uint32_t* ms) {
  if (f.len < 6) return false;
  uint32_t hh, mm, ss;
  if (!fixed_digits(f.p, 2, &hh) || !fixed_digits(f.p + 2, 2, &mm) ||
      !fixed_digits(f.p + 4, 2, &ss)) {
    return false;
  }
  if (hh > 23 || mm > 59 || ss > 60) return false;
  uint32_t frac_ms = 0;
  if (f.len > 6) {
    if (f.p[6] != '.' || f.len == 7) return false;
    uint32_t scale = 100;
    for (uint8_t i = 7; i < f.len; ++i) {
      if (!is_digit(f.p[i])) return false;
      frac_ms += static_cast<uint32_t>(f.p[i] - '0') * scale;
      scale /= 10;
    }
  }
  *ms = ((hh * 60 + mm) * 60 + ss) * 1000 + frac_ms;
  return true;
}

// (d)ddmm[.mmmm...] with `deg_digits` degree digits -> 1e-7 degrees (unsigned).
bool angle_field(const Field& f, uint8_t deg_digits, uint32_t max_deg, int32_t* e7) {
  const uint8_t int_len = static_cast<uint8_t>(deg_digits + 2);
  if (f.len < int_len) return false;
  uint32_t deg, minutes;
  if (!fixed_digits(f.p, deg_digits, &deg) || !fixed_digits(f.p + deg_digits, 2, &minutes)) {
    return false;
  }
  if (minutes > 59 || deg > max_deg) return false;
  uint32_t frac = 0;  // minutes' decimals scaled to 7 digits
  if (f.len > int_len) {
    if (f.p[int_len] != '.' || f.len == int_len + 1) return false;
    uint32_t scale = 1000000UL;
    for (uint8_t i = static_cast<uint8_t>(int_len + 1); i < f.len; ++i) {
      if (!is_digit(f.p[i])) return false;
      frac += static_cast<uint32_t>(f.p[i] - '0') * scale;
      scale /= 10;  // beyond the 7th digit scale is 0: the digit is ignored
    }
  }
  const uint32_t minutes_e7 = minutes * 10000000UL + frac;  // < 6e8
  const uint32_t value = deg * 10000000UL + (minutes_e7 + 30) / 60;
  if (value > max_deg * 10000000UL) return false;
  *e7 = static_cast<int32_t>(value);
  return true;
}

}  // namespace

uint8_t wire_fix_quality(uint8_t gga_quality) {
  switch (gga_quality) {
    case GGA_GPS:
    case GGA_DGPS:
    case GGA_RTK_FIXED:
    case GGA_RTK_FLOAT:
      return gga_quality;
    default:
      return 0;
  }
}

NmeaResult parse_gga(const char* s, size_t len, GgaFix* out) {
  if (s == 0 || len == 0 || s[0] != '$') return NMEA_NO_START;
  while (len > 0 && (s[len - 1] == '\n' || s[len - 1] == '\r')) --len;
  if (len > 255) return NMEA_TOO_LONG;

  // "*hh" ends the sentence; the checksum is the XOR of everything between '$' and '*'.
  if (len < 4 || s[len - 3] != '*') return NMEA_NO_CHECKSUM;
  const int8_t hi = hex_value(s[len - 2]);
  const int8_t lo = hex_value(s[len - 1]);
  if (hi < 0 || lo < 0) return NMEA_NO_CHECKSUM;
  const size_t body_end = len - 3;
  uint8_t sum = 0;
  for (size_t i = 1; i < body_end; ++i) {
    const char c = s[i];
    if (c < 0x20 || c > 0x7E || c == '$' || c == '*') return NMEA_MALFORMED;
    sum = static_cast<uint8_t>(sum ^ static_cast<uint8_t>(c));
  }
  if (sum != static_cast<uint8_t>((hi << 4) | lo)) return NMEA_BAD_CHECKSUM;

  // Address field: two talker letters + sentence formatter.
  size_t i = 1;
  while (i < body_end && s[i] != ',') ++i;
  const size_t address_len = i - 1;
  if (address_len != 5 || s[3] != 'G' || s[4] != 'G' || s[5] != 'A') {
    return address_len >= 2 ? NMEA_NOT_GGA : NMEA_MALFORMED;
  }

  Field fields[kGgaFields];
  uint8_t n = 0;
  while (i < body_end) {  // s[i] == ','
    const size_t start = i + 1;
    size_t end = start;
    while (end < body_end && s[end] != ',') ++end;
    if (n == kGgaFields) return NMEA_MALFORMED;  // too many fields
    fields[n].p = s + start;
    fields[n].len = static_cast<uint8_t>(end - start);
    ++n;
    i = end;
  }
  if (n != kGgaFields) return NMEA_MALFORMED;

  GgaFix fix;
  fix.utc_ms_of_day = kNoUtcTime;
  fix.lat_e7 = 0;
  fix.lon_e7 = 0;
  if (fields[0].len != 0 && !time_field(fields[0], &fix.utc_ms_of_day)) return NMEA_MALFORMED;

  const bool lat_empty = fields[1].len == 0 && fields[2].len == 0;
  const bool lon_empty = fields[3].len == 0 && fields[4].len == 0;
  if (lat_empty != lon_empty) return NMEA_MALFORMED;
  fix.has_position = !lat_empty;
  if (fix.has_position) {
    if (!angle_field(fields[1], 2, 90, &fix.lat_e7)) return NMEA_MALFORMED;
    if (fields[2].len != 1 || (fields[2].p[0] != 'N' && fields[2].p[0] != 'S')) {
      return NMEA_MALFORMED;
    }
    if (fields[2].p[0] == 'S') fix.lat_e7 = -fix.lat_e7;
    if (!angle_field(fields[3], 3, 180, &fix.lon_e7)) return NMEA_MALFORMED;
    if (fields[4].len != 1 || (fields[4].p[0] != 'E' && fields[4].p[0] != 'W')) {
      return NMEA_MALFORMED;
    }
    if (fields[4].p[0] == 'W') fix.lon_e7 = -fix.lon_e7;
  }

  uint32_t quality;
  if (!uint_field(fields[5], 1, &quality) || quality > GGA_SIMULATION) return NMEA_MALFORMED;
  if (quality != GGA_INVALID && !fix.has_position) return NMEA_MALFORMED;
  fix.quality = static_cast<uint8_t>(quality);

  uint32_t satellites = 0;
  if (fields[6].len != 0 && !uint_field(fields[6], 3, &satellites)) return NMEA_MALFORMED;
  fix.satellites = static_cast<uint8_t>(satellites > 255 ? 255 : satellites);

  // HDOP, altitude, M, geoid separation, M, age of differential data, station id.
  if (!empty_or_decimal(fields[7]) || !empty_or_decimal(fields[8]) ||
      !empty_or_unit_m(fields[9]) || !empty_or_decimal(fields[10]) ||
      !empty_or_unit_m(fields[11]) || !empty_or_decimal(fields[12])) {
    return NMEA_MALFORMED;
  }
  uint32_t station;
  if (fields[13].len != 0 && !uint_field(fields[13], 4, &station)) return NMEA_MALFORMED;

  if (out != 0) *out = fix;
  return NMEA_OK;
}

bool NmeaReader::feed(char c, NmeaResult* result, GgaFix* fix) {
  if (c == '$') {  // a new sentence always restarts, whatever came before
    buf_[0] = c;
    len_ = 1;
    state_ = kInSentence;
    return false;
  }
  if (state_ == kIdle) return false;
  if (c == '\n') {
    const bool overflow = state_ == kOverflow;
    const uint8_t len = len_;
    reset();
    const NmeaResult r = overflow ? NMEA_TOO_LONG : parse_gga(buf_, len, fix);
    if (result != 0) *result = r;
    return true;
  }
  if (c == '\r' || state_ == kOverflow) return false;
  if (len_ >= kCapacity) {
    state_ = kOverflow;
    return false;
  }
  buf_[len_++] = c;
  return false;
}

}  // namespace amz
