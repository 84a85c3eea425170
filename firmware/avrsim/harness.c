// The flashed image, executed: runs the very robot.elf that `make firmware` builds on simavr's
// emulated ATmega328P at 16 MHz on the robot's board (board.c), with its inputs (GPS sentences on the UART at their
// baud rate and rate, the battery on ADC0, and with --radio the RFM69 below), and reports what
// only the real image can show, as one JSON object on stdout (its last line):
//
//   passes, loop_mean_us, loop_max_us  loop() passes, timed between the watchdog resets that
//                                      end each pass (interrupts included);
//   boot_us                            power-on to the end of setup() (its watchdog start);
//   stack_used_bytes, stack_free_bytes the deepest the stack reached in painted RAM, and what
//                                      lies between it and the end of the static data;
//   resets                             resets during the run, the watchdog's or --reset-at's
//                                      (a healthy image left alone: 0);
//   gps_bytes                          bytes delivered on the UART;
//   hung_at_s, hang_to_isr_us,         with --hang-at: when the loop hung, and from then to
//   hang_to_reset_us                   the watchdog's interrupt (which cuts the drive) and
//                                      to the reset;
//   eeprom0                            the EEPROM's first byte at the end (the e-stop latch);
//   asleep_share                       the share of the cycles the chip spent in its idle
//                                      sleep between passes (waiting for an interrupt).
//
// Before that line, with --radio FRAMES: an RFM69 on the SPI bus (chip select D10), registers and
// FIFO as the robot's driver uses them (firmware/robot/rfm69.cpp), and on the air the frames
// of FRAMES (a line each: the emulated second at which it arrives, then its bytes in hex,
// length byte first), each delivered when due and the radio listening. What the image sends is
// printed as `tx SECONDS HEX`, and the motor outputs every 10 ms as
// `motor SECONDS DUTY ENABLE DIRECTION` (PWM duty 0-255 on D9, D7, D8).
//
// Time is the emulated chip's cycles, never the host's clock. Usage:
//   avr_harness ELF DATA_END SECONDS GPS_FILE [--hang-at S] [--reset-at S] [--radio FRAMES]
// DATA_END is the first RAM address above the static data (avr-nm's `_end`), GPS_FILE one
// NMEA sentence per line, sent round and round at 10 Hz (the receiver's rate). --hang-at
// makes loop() hang once, from the first pass to end after S seconds: its watchdog reset is
// replaced by a jump to itself until the chip resets. --reset-at resets the chip once at S
// seconds (its reset pin; RAM is left as it was, the EEPROM kept).
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <sim_avr.h>

#include "board.h"

#define F_CPU_HZ AMZ_BOARD_F_CPU_HZ
#define GPS_PERIOD_S 0.1
#define BATTERY_PIN_MV 4000  // 60 V (the simulator's full battery) through the 15:1 divider
#define PAINT 0xA5
#define WDR_OPCODE 0x95A8
#define SELF_JUMP_OPCODE 0xCFFF  // rjmp .-2
#define WDT_VECTOR_ADDRESS (6 * 4)  // WDT_vect, the ATmega328P's seventh vector
#define MAX_GPS_BYTES 8192
#define MAX_AIR_FRAMES 4096
// The first watchdog resets are the start-up's (wdt_disable before main, wdt_enable at the end
// of setup()); each one after ends a loop() pass.
#define BOOT_WDRS 2

static double us(avr_cycle_count_t cycles) { return (double)cycles * 1e6 / (double)F_CPU_HZ; }

// The base station's frames, each on the air from its second on.
typedef struct {
  double at_s;
  uint8_t len;
  uint8_t bytes[AMZ_BOARD_FRAME_BYTES];
} air_frame_t;

static int read_air(const char* path, air_frame_t* out, int cap) {
  FILE* f = fopen(path, "r");
  if (!f) {
    perror(path);
    exit(2);
  }
  int n = 0;
  char hex[2 * AMZ_BOARD_FRAME_BYTES + 2];
  double at_s;
  while (n < cap && fscanf(f, "%lf %133s", &at_s, hex) == 2) {
    const size_t digits = strlen(hex);
    if (digits % 2 != 0 || digits / 2 > AMZ_BOARD_FRAME_BYTES || digits == 0) {
      fprintf(stderr, "%s: frame %d is not 1-%d bytes of hex\n", path, n + 1,
              AMZ_BOARD_FRAME_BYTES);
      exit(2);
    }
    out[n].at_s = at_s;
    out[n].len = (uint8_t)(digits / 2);
    for (size_t i = 0; i < digits / 2; ++i) {
      unsigned byte;
      if (sscanf(hex + 2 * i, "%2x", &byte) != 1) exit(2);
      out[n].bytes[i] = (uint8_t)byte;
    }
    if (n > 0 && at_s < out[n - 1].at_s) {
      fprintf(stderr, "%s: frames out of order\n", path);
      exit(2);
    }
    ++n;
  }
  fclose(f);
  return n;
}

// What the image put on the air: `tx SECONDS HEX`, at the cycle its transmission began.
static void print_sent(amz_board_t* board) {
  uint8_t frame[AMZ_BOARD_FRAME_BYTES];
  uint64_t at = 0;
  int n;
  while ((n = amz_board_air_out(board, frame, sizeof frame, &at)) > 0) {
    printf("tx %.6f ", (double)at / F_CPU_HZ);
    for (int i = 0; i < n; ++i) printf("%02x", frame[i]);
    printf("\n");
  }
}

// The motor outputs as the board's driver sees them: PWM on D9 (OC1A), enable D7, direction D8.
static void print_motor(amz_board_t* board) {
  unsigned duty;
  int enable, direction;
  amz_board_motor(board, &duty, &enable, &direction);
  printf("motor %.6f %u %d %d\n", (double)amz_board_cycle(board) / F_CPU_HZ, duty, enable,
         direction);
}

static size_t read_gps(const char* path, uint8_t* out, size_t cap, size_t* sentences) {
  FILE* f = fopen(path, "rb");
  if (!f) {
    perror(path);
    exit(2);
  }
  size_t n = fread(out, 1, cap, f);
  fclose(f);
  *sentences = 0;
  for (size_t i = 0; i < n; ++i) {
    if (out[i] == '\n') ++*sentences;
  }
  return n;
}

int main(int argc, char** argv) {
  if (argc < 5) {
    fprintf(stderr,
            "usage: %s ELF DATA_END SECONDS GPS_FILE [--hang-at S] [--reset-at S] "
            "[--radio FRAMES]\n",
            argv[0]);
    return 2;
  }
  double hang_at_s = -1.0, reset_at_s = -1.0;
  const char* radio_path = NULL;
  for (int i = 5; i + 1 < argc; i += 2) {
    if (strcmp(argv[i], "--hang-at") == 0) {
      hang_at_s = atof(argv[i + 1]);
    } else if (strcmp(argv[i], "--reset-at") == 0) {
      reset_at_s = atof(argv[i + 1]);
    } else if (strcmp(argv[i], "--radio") == 0) {
      radio_path = argv[i + 1];
    } else {
      fprintf(stderr, "unknown option %s\n", argv[i]);
      return 2;
    }
  }
  if ((argc - 5) % 2 != 0) {
    fprintf(stderr, "option %s wants a value\n", argv[argc - 1]);
    return 2;
  }
  const uint32_t data_end = (uint32_t)strtoul(argv[2], NULL, 0) & 0xFFFF;
  const double seconds = atof(argv[3]);
  static uint8_t gps[MAX_GPS_BYTES];
  size_t sentences = 0;
  const size_t gps_len = read_gps(argv[4], gps, sizeof gps, &sentences);
  if (gps_len == 0 || sentences == 0) {
    fprintf(stderr, "%s: no sentences\n", argv[4]);
    return 2;
  }

  const int with_radio = radio_path != NULL;
  amz_board_t* board = amz_board_create(argv[1], BATTERY_PIN_MV, with_radio);
  if (board == NULL) {
    fprintf(stderr, "%s: not an AVR ELF image\n", argv[1]);
    return 2;
  }
  avr_t* avr = amz_board_avr(board);
  if (data_end <= 0x100 || data_end > avr->ramend) {
    fprintf(stderr, "DATA_END 0x%x outside RAM\n", data_end);
    return 2;
  }
  // Paint the RAM between the static data and the top: what the stack ever touches shows.
  memset(avr->data + data_end, PAINT, (size_t)avr->ramend + 1 - data_end);

  static air_frame_t air[MAX_AIR_FRAMES];
  const int air_count = with_radio ? read_air(radio_path, air, MAX_AIR_FRAMES) : 0;
  int air_next = 0;
  const avr_cycle_count_t motor_every = F_CPU_HZ / 100;  // 10 ms
  avr_cycle_count_t next_motor = 0;

  const avr_cycle_count_t end = (avr_cycle_count_t)(seconds * F_CPU_HZ);
  amz_board_uart_repeat(board, gps, (int)gps_len, GPS_PERIOD_S);

  unsigned wdrs = 0, resets = 0;
  avr_cycle_count_t slept = 0;  // cycles spent in the sketch's idle sleep
  avr_cycle_count_t last_wdr = 0, boot = 0, loop_max = 0, loop_sum = 0;
  unsigned long passes = 0;
  avr_flashaddr_t last_pc = avr->pc;
  int state = cpu_Running;
  // The hang: where it was put, when, and what followed.
  avr_flashaddr_t hang_pc = 0;
  avr_cycle_count_t hang_at = 0, hang_isr = 0, hang_reset = 0;
  int hung = 0;

  while (avr->cycle < end && state != cpu_Done && state != cpu_Crashed) {
    const avr_flashaddr_t pc = avr->pc;
    if (pc == 0 && last_pc != 0 && avr->cycle > 0) {  // the reset vector again
      ++resets;
      wdrs = 0;
      if (hung == 1) {  // the hang was transient: the next boot runs the image as built
        avr->flash[hang_pc] = (uint8_t)(WDR_OPCODE & 0xFF);
        avr->flash[hang_pc + 1] = (uint8_t)(WDR_OPCODE >> 8);
        hang_reset = avr->cycle;
        hung = 2;
      }
    }
    if (pc == WDT_VECTOR_ADDRESS && hung == 1 && hang_isr == 0) hang_isr = avr->cycle;
    last_pc = pc;
    const uint16_t opcode = (uint16_t)(avr->flash[pc] | (avr->flash[pc + 1] << 8));
    if (opcode == WDR_OPCODE && hung == 0 && hang_at_s >= 0 && wdrs >= BOOT_WDRS &&
        avr->cycle >= (avr_cycle_count_t)(hang_at_s * F_CPU_HZ)) {
      hang_pc = pc;
      avr->flash[pc] = (uint8_t)(SELF_JUMP_OPCODE & 0xFF);
      avr->flash[pc + 1] = (uint8_t)(SELF_JUMP_OPCODE >> 8);
      hang_at = avr->cycle;
      hung = 1;
    } else if (opcode == WDR_OPCODE) {
      ++wdrs;
      if (wdrs == BOOT_WDRS) {
        if (boot == 0) boot = avr->cycle;  // the first boot's; a reset's comes later
      } else if (wdrs > BOOT_WDRS) {
        const avr_cycle_count_t pass = avr->cycle - last_wdr;
        loop_sum += pass;
        if (pass > loop_max) loop_max = pass;
        ++passes;
      }
      last_wdr = avr->cycle;
    }
    if (reset_at_s >= 0 && avr->cycle >= (avr_cycle_count_t)(reset_at_s * F_CPU_HZ)) {
      reset_at_s = -1.0;
      amz_board_reset(board);
      continue;
    }
    if (with_radio) {
      while (air_next < air_count && (double)avr->cycle >= air[air_next].at_s * F_CPU_HZ) {
        amz_board_air_in(board, air[air_next].bytes, air[air_next].len, -60);
        ++air_next;
      }
      print_sent(board);
      if (avr->cycle >= next_motor) {
        print_motor(board);
        next_motor += motor_every;
      }
    }
    const avr_cycle_count_t before = avr->cycle;
    const int sleeping = avr->state == cpu_Sleeping;
    state = amz_board_step(board);
    if (sleeping) slept += avr->cycle - before;
  }

  uint32_t deepest = (uint32_t)avr->ramend + 1;
  for (uint32_t a = data_end; a <= avr->ramend; ++a) {
    if (avr->data[a] != PAINT) {
      deepest = a;
      break;
    }
  }
  if (with_radio) print_sent(board);
  const int eeprom0 = amz_board_eeprom(board, 0);
  unsigned long sent = 0;
  const unsigned long delivered = amz_board_air_counts(board, &sent);
  const unsigned stack_used = (unsigned)(avr->ramend + 1 - deepest);
  const unsigned stack_free = deepest - data_end;
  printf(
      "{\"emulated_s\": %.3f, \"state\": %d, \"boot_us\": %.1f, \"passes\": %lu, "
      "\"loop_mean_us\": %.1f, \"loop_max_us\": %.1f, \"stack_used_bytes\": %u, "
      "\"stack_free_bytes\": %u, \"ram_bytes\": %u, \"data_end\": %u, \"resets\": %u, "
      "\"gps_bytes\": %lu, \"hang_to_isr_us\": %.1f, \"hang_to_reset_us\": %.1f, "
      "\"hung_at_s\": %.6f, \"radio_received\": %lu, \"radio_sent\": %lu, "
      "\"eeprom0\": %d, \"asleep_share\": %.3f}\n",
      (double)avr->cycle / F_CPU_HZ, state, us(boot), passes,
      passes ? us(loop_sum) / (double)passes : 0.0, us(loop_max), stack_used, stack_free,
      (unsigned)(avr->ramend + 1 - 0x100), data_end, resets, amz_board_uart_sent(board),
      hang_isr ? us(hang_isr - hang_at) : -1.0, hang_reset ? us(hang_reset - hang_at) : -1.0,
      hung ? (double)hang_at / F_CPU_HZ : -1.0, delivered, sent, eeprom0,
      avr->cycle ? (double)slept / (double)avr->cycle : 0.0);
  amz_board_destroy(board);
  return state == cpu_Crashed ? 1 : 0;
}
