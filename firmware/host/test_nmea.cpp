// GGA parsing: checksum, RTK qualities, 1e-7 degree integers, clean rejects.
#include <stdio.h>
#include <string.h>

#include "harness.h"
#include "nmea.h"

using namespace amz;

namespace {

// "$" + body + "*HH": the checksum computed here, so tests can build any sentence.
const char* sentence(const char* body) {
  static char buf[256];
  uint8_t sum = 0;
  for (const char* p = body; *p != '\0'; ++p) sum = static_cast<uint8_t>(sum ^ *p);
  snprintf(buf, sizeof buf, "$%s*%02X\r\n", body, sum);
  return buf;
}

NmeaResult parse(const char* s, GgaFix* fix) { return parse_gga(s, strlen(s), fix); }

}  // namespace

TEST(gga_textbook_example_parses) {
  // The classic example sentence, its checksum as published.
  GgaFix fix;
  CHECK_EQ(parse("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47", &fix),
           NMEA_OK);
  CHECK_EQ(fix.lat_e7, 481173000L);  // 48 deg 07.038' = 48.1173 deg
  CHECK_EQ(fix.lon_e7, 115166667L);  // 11 deg 31.000' = 11.5166667 deg (rounded)
  CHECK_EQ(fix.quality, GGA_GPS);
  CHECK_EQ(fix.satellites, 8);
  CHECK_EQ(fix.utc_ms_of_day, ((12 * 60 + 35) * 60 + 19) * 1000UL);
  CHECK(fix.has_position);
}

TEST(gga_rtk_fixed_at_the_building_centre) {
  GgaFix fix;
  CHECK_EQ(parse(sentence("GNGGA,101530.20,4038.05032,N,00839.60090,W,4,14,0.62,32.1,M,50.2,M,"
                          "1.0,0000"),
                 &fix),
           NMEA_OK);
  CHECK_EQ(fix.lat_e7, 406341720L);  // 40.634172
  CHECK_EQ(fix.lon_e7, -86600150L);  // -8.660015
  CHECK_EQ(fix.quality, GGA_RTK_FIXED);
  CHECK_EQ(wire_fix_quality(fix.quality), 4);
  CHECK_EQ(fix.satellites, 14);
  CHECK_EQ(fix.utc_ms_of_day, ((10 * 60 + 15) * 60 + 30) * 1000UL + 200);
}

TEST(gga_rtk_float_southern_and_eastern_hemispheres) {
  GgaFix fix;
  CHECK_EQ(parse(sentence("GPGGA,000000.00,3351.3674040,S,15112.5607360,E,5,09,1.1,10.0,M,"
                          "22.0,M,2.5,0123"),
                 &fix),
           NMEA_OK);
  // 33 deg 51.367404' = 33.8561234 deg; 151 deg 12.560736' = 151.2093456 deg
  CHECK_EQ(fix.lat_e7, -338561234L);
  CHECK_EQ(fix.lon_e7, 1512093456L);
  CHECK_EQ(fix.quality, GGA_RTK_FLOAT);
  CHECK_EQ(wire_fix_quality(fix.quality), 5);
}

TEST(gga_extra_minute_digits_are_ignored_and_rounding_is_exact) {
  GgaFix fix;
  CHECK_EQ(parse(sentence("GNGGA,120000,0000.00000003,N,00000.00000009,E,1,05,1.0,0,M,0,M,,"),
                 &fix),
           NMEA_OK);
  CHECK_EQ(fix.lat_e7, 0);
  CHECK_EQ(fix.lon_e7, 0);
  CHECK_EQ(parse(sentence("GNGGA,120000,0000.0000030,N,17959.9999999,W,1,05,1.0,0,M,0,M,,"),
                 &fix),
           NMEA_OK);
  CHECK_EQ(fix.lat_e7, 1);  // 0.000003' = 0.5e-7 deg, rounds up
  CHECK_EQ(fix.lon_e7, -1800000000L);
}

TEST(gga_without_fix_has_no_position) {
  GgaFix fix;
  CHECK_EQ(parse(sentence("GPGGA,,,,,,0,00,99.99,,,,,,"), &fix), NMEA_OK);
  CHECK(!fix.has_position);
  CHECK_EQ(fix.quality, GGA_INVALID);
  CHECK_EQ(fix.utc_ms_of_day, kNoUtcTime);
  CHECK_EQ(wire_fix_quality(fix.quality), 0);
}

TEST(gga_quality_outside_the_wire_enum_maps_to_no_fix) {
  CHECK_EQ(wire_fix_quality(GGA_PPS), 0);
  CHECK_EQ(wire_fix_quality(GGA_ESTIMATED), 0);
  CHECK_EQ(wire_fix_quality(GGA_MANUAL), 0);
  CHECK_EQ(wire_fix_quality(GGA_SIMULATION), 0);
  CHECK_EQ(wire_fix_quality(GGA_DGPS), 2);
}

TEST(gga_checksum_is_verified) {
  GgaFix fix;
  fix.lat_e7 = 77;
  CHECK_EQ(parse("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*48", &fix),
           NMEA_BAD_CHECKSUM);
  CHECK_EQ(fix.lat_e7, 77);  // untouched on failure
  // One flipped digit in the body.
  CHECK_EQ(parse("$GPGGA,123519,4807.039,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47", &fix),
           NMEA_BAD_CHECKSUM);
  // Lower-case hex is accepted.
  char lower[128];
  snprintf(lower, sizeof lower, "%s", sentence("GPGGA,,,,,,0,00,,,,,,,"));
  for (char* p = strchr(lower, '*'); p != 0 && *p != '\0'; ++p) {
    if (*p >= 'A' && *p <= 'F') *p = static_cast<char>(*p - 'A' + 'a');
  }
  CHECK_EQ(parse(lower, &fix), NMEA_OK);
}

TEST(gga_malformed_sentences_are_rejected_cleanly) {
  GgaFix fix;
  CHECK_EQ(parse("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47", &fix),
           NMEA_NO_START);
  CHECK_EQ(parse("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,", &fix),
           NMEA_NO_CHECKSUM);
  CHECK_EQ(parse("$GPGGA,123519*4", &fix), NMEA_NO_CHECKSUM);
  CHECK_EQ(parse("$GPGGA,1*ZZ", &fix), NMEA_NO_CHECKSUM);
  CHECK_EQ(parse("", &fix), NMEA_NO_START);
  CHECK_EQ(parse("$", &fix), NMEA_NO_CHECKSUM);
  const char* bad[] = {
      "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,",        // 13 fields
      "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,,",      // 15 fields
      "GPGGA,123519,4860.000,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",       // 60 minutes
      "GPGGA,123519,9100.000,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",       // 91 degrees
      "GPGGA,123519,9000.001,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",       // past the pole
      "GPGGA,123519,4807.038,N,18100.000,E,1,08,0.9,545.4,M,46.9,M,,",       // 181 degrees
      "GPGGA,123519,4807.038,X,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",       // hemisphere
      "GPGGA,123519,4807.038,N,01131.000,N,1,08,0.9,545.4,M,46.9,M,,",       // hemisphere
      "GPGGA,123519,4807.038,,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",        // half empty
      "GPGGA,123519,4807.038,N,,,1,08,0.9,545.4,M,46.9,M,,",                 // no longitude
      "GPGGA,123519,48O7.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",       // letter O
      "GPGGA,123519,4807.,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",          // dot, no digits
      "GPGGA,123519,807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",        // short degrees
      "GPGGA,123519,4807.038,N,01131.000,E,9,08,0.9,545.4,M,46.9,M,,",       // quality 9
      "GPGGA,123519,4807.038,N,01131.000,E,,08,0.9,545.4,M,46.9,M,,",        // no quality
      "GPGGA,123519,4807.038,N,01131.000,E,4x,08,0.9,545.4,M,46.9,M,,",      // quality junk
      "GPGGA,,,,,,4,08,0.9,545.4,M,46.9,M,,",                                // fix, no position
      "GPGGA,123519,4807.038,N,01131.000,E,1,8a,0.9,545.4,M,46.9,M,,",       // satellites
      "GPGGA,250000,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",       // hour 25
      "GPGGA,12351,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,",        // short time
      "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,F,46.9,M,,",       // feet
      "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9.1,545.4,M,46.9,M,,",     // HDOP
      "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,12345",  // station id
      "GPGGA",                                                               // no fields
      "G,",                                                                  // bad address
  };
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; ++i) {
    fix.lat_e7 = 77;
    const NmeaResult r = parse(sentence(bad[i]), &fix);
    CHECK_MSG(r == NMEA_MALFORMED, bad[i]);
    CHECK_EQ(fix.lat_e7, 77);
  }
  // A control character inside the body.
  CHECK_EQ(parse(sentence("GPGGA,12\x01" "3519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
                 &fix),
           NMEA_MALFORMED);
}

TEST(other_sentences_are_not_gga) {
  GgaFix fix;
  CHECK_EQ(parse(sentence("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W"),
                 &fix),
           NMEA_NOT_GGA);
  CHECK_EQ(parse(sentence("GNGSA,A,3,01,02,,,,,,,,,,,1.0,1.0,1.0"), &fix), NMEA_NOT_GGA);
}

TEST(reader_assembles_sentences_from_a_noisy_stream) {
  NmeaReader reader;
  char stream[600];
  snprintf(stream, sizeof stream, "noise\xff\r\n%s", sentence("GPRMC,1,A"));
  size_t len = strlen(stream);
  // A sentence cut short by a new '$' is dropped; the next one parses.
  const char* cut = "$GNGGA,101530.20,4038.0";
  memcpy(stream + len, cut, strlen(cut));
  len += strlen(cut);
  const char* good =
      sentence("GNGGA,101530.20,4038.05032,N,00839.60090,W,4,14,0.62,32.1,M,50.2,M,1.0,0000");
  memcpy(stream + len, good, strlen(good));
  len += strlen(good);

  int lines = 0;
  int ok = 0;
  int not_gga = 0;
  GgaFix fix;
  for (size_t i = 0; i < len; ++i) {
    NmeaResult r;
    if (reader.feed(stream[i], &r, &fix)) {
      ++lines;
      if (r == NMEA_OK) ++ok;
      if (r == NMEA_NOT_GGA) ++not_gga;
    }
  }
  CHECK_EQ(lines, 2);
  CHECK_EQ(not_gga, 1);
  CHECK_EQ(ok, 1);
  CHECK_EQ(fix.lat_e7, 406341720L);
}

TEST(reader_reports_an_over_long_line_and_recovers) {
  NmeaReader reader;
  NmeaResult r = NMEA_OK;
  GgaFix fix;
  bool done = reader.feed('$', &r, &fix);
  for (int i = 0; i < 300; ++i) done = reader.feed('1', &r, &fix);
  CHECK(!done);
  CHECK(reader.feed('\n', &r, &fix));
  CHECK_EQ(r, NMEA_TOO_LONG);
  const char* good = sentence("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,");
  int completed = 0;
  for (const char* p = good; *p != '\0'; ++p) {
    if (reader.feed(*p, &r, &fix)) ++completed;
  }
  CHECK_EQ(completed, 1);
  CHECK_EQ(r, NMEA_OK);
}

TEST(reader_survives_random_bytes) {
  NmeaReader reader;
  uint32_t state = 7;
  int lines = 0;
  GgaFix fix;
  for (int i = 0; i < 300000; ++i) {
    state = state * 1664525UL + 1013904223UL;
    char c = static_cast<char>(state >> 24);
    if ((state & 0xF00) == 0) c = '$';
    if ((state & 0xF000) == 0) c = '\n';
    NmeaResult r;
    if (reader.feed(c, &r, &fix)) {
      ++lines;
      CHECK(r <= NMEA_TOO_LONG);
    }
  }
  CHECK(lines > 0);
}
