// The flashed image, executed: runs the very robot.elf that `make firmware` builds on simavr's
// emulated ATmega328P at 16 MHz, with the board's inputs it can have without a radio (GPS
// sentences on the UART at their baud rate and rate, the battery on ADC0), and reports what
// only the real image can show, as one JSON object on stdout:
//
//   passes, loop_mean_us, loop_max_us  loop() passes, timed between the watchdog resets that
//                                      end each pass (interrupts included);
//   boot_us                            power-on to the end of setup() (its watchdog start);
//   stack_used_bytes, stack_free_bytes the deepest the stack reached in painted RAM, and what
//                                      lies between it and the end of the static data;
//   resets                             watchdog resets during the run (a healthy image: 0);
//   gps_bytes                          bytes delivered on the UART;
//   hang_to_isr_us, hang_to_reset_us   with HANG_AT_S: from the hang to the watchdog's
//                                      interrupt (which cuts the drive) and to the reset.
//
// Time is the emulated chip's cycles, never the host's clock. Usage:
//   avr_harness ELF DATA_END SECONDS GPS_FILE [HANG_AT_S]
// DATA_END is the first RAM address above the static data (avr-nm's `_end`), GPS_FILE one
// NMEA sentence per line, sent round and round at 10 Hz (the receiver's rate). HANG_AT_S
// makes loop() hang once, from the first pass to end after that time: its watchdog reset is
// replaced by a jump to itself until the chip resets.
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <sim_avr.h>
#include <sim_elf.h>
#include <avr_adc.h>
#include <avr_uart.h>

#define F_CPU_HZ 16000000UL
#define GPS_BAUD 115200UL
#define GPS_PERIOD_S 0.1
#define BATTERY_PIN_MV 1600  // 24 V through the board's 15:1 divider
#define PAINT 0xA5
#define WDR_OPCODE 0x95A8
#define SELF_JUMP_OPCODE 0xCFFF  // rjmp .-2
#define WDT_VECTOR_ADDRESS (6 * 4)  // WDT_vect, the ATmega328P's seventh vector
#define MAX_GPS_BYTES 8192
// The first watchdog resets are the start-up's (wdt_disable before main, wdt_enable at the end
// of setup()); each one after ends a loop() pass.
#define BOOT_WDRS 2

// The emulator's "sleep" keeps it in step with the host's clock: here emulated time runs as
// fast as the host can, and only cycles count.
static void no_wall_clock(avr_t* avr, avr_cycle_count_t how_long) {
  (void)avr;
  (void)how_long;
}

static double us(avr_cycle_count_t cycles) { return (double)cycles * 1e6 / (double)F_CPU_HZ; }

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
  if (argc != 5 && argc != 6) {
    fprintf(stderr, "usage: %s ELF DATA_END SECONDS GPS_FILE [HANG_AT_S]\n", argv[0]);
    return 2;
  }
  const double hang_at_s = argc == 6 ? atof(argv[5]) : -1.0;
  const uint32_t data_end = (uint32_t)strtoul(argv[2], NULL, 0) & 0xFFFF;
  const double seconds = atof(argv[3]);
  static uint8_t gps[MAX_GPS_BYTES];
  size_t sentences = 0;
  const size_t gps_len = read_gps(argv[4], gps, sizeof gps, &sentences);
  if (gps_len == 0 || sentences == 0) {
    fprintf(stderr, "%s: no sentences\n", argv[4]);
    return 2;
  }

  elf_firmware_t firmware;
  memset(&firmware, 0, sizeof firmware);
  if (elf_read_firmware(argv[1], &firmware) != 0) {
    fprintf(stderr, "%s: not an AVR ELF image\n", argv[1]);
    return 2;
  }
  avr_t* avr = avr_make_mcu_by_name("atmega328p");
  if (!avr) return 2;
  avr_init(avr);
  avr->frequency = F_CPU_HZ;
  avr->log = LOG_ERROR;
  avr->sleep = no_wall_clock;
  avr_load_firmware(avr, &firmware);
  if (data_end <= 0x100 || data_end > avr->ramend) {
    fprintf(stderr, "DATA_END 0x%x outside RAM\n", data_end);
    return 2;
  }
  // Paint the RAM between the static data and the top: what the stack ever touches shows.
  memset(avr->data + data_end, PAINT, (size_t)avr->ramend + 1 - data_end);

  avr_irq_t* uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  avr_irq_t* adc0 = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0);
  avr_raise_irq(adc0, BATTERY_PIN_MV);

  const avr_cycle_count_t end = (avr_cycle_count_t)(seconds * F_CPU_HZ);
  const avr_cycle_count_t byte_cycles = F_CPU_HZ * 10 / GPS_BAUD;  // start, 8 data, stop
  const avr_cycle_count_t burst_cycles = (avr_cycle_count_t)(GPS_PERIOD_S * F_CPU_HZ);
  avr_cycle_count_t next_byte = 0, burst_start = 0;
  size_t gps_pos = 0, gps_bytes = 0;
  int in_burst = 1;

  unsigned wdrs = 0, resets = 0;
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
    // One sentence burst every GPS_PERIOD_S, its bytes one byte-time apart.
    if (!in_burst && avr->cycle >= burst_start + burst_cycles) {
      in_burst = 1;
      burst_start += burst_cycles;
    }
    if (in_burst && avr->cycle >= next_byte) {
      const uint8_t byte = gps[gps_pos];
      avr_raise_irq(uart_in, byte);
      ++gps_bytes;
      gps_pos = (gps_pos + 1) % gps_len;
      next_byte = avr->cycle + byte_cycles;
      if (byte == '\n') in_burst = 0;
    }
    state = avr_run(avr);
  }

  uint32_t deepest = (uint32_t)avr->ramend + 1;
  for (uint32_t a = data_end; a <= avr->ramend; ++a) {
    if (avr->data[a] != PAINT) {
      deepest = a;
      break;
    }
  }
  const unsigned stack_used = (unsigned)(avr->ramend + 1 - deepest);
  const unsigned stack_free = deepest - data_end;
  printf(
      "{\"emulated_s\": %.3f, \"state\": %d, \"boot_us\": %.1f, \"passes\": %lu, "
      "\"loop_mean_us\": %.1f, \"loop_max_us\": %.1f, \"stack_used_bytes\": %u, "
      "\"stack_free_bytes\": %u, \"ram_bytes\": %u, \"data_end\": %u, \"resets\": %u, "
      "\"gps_bytes\": %zu, \"hang_to_isr_us\": %.1f, \"hang_to_reset_us\": %.1f}\n",
      (double)avr->cycle / F_CPU_HZ, state, us(boot), passes,
      passes ? us(loop_sum) / (double)passes : 0.0, us(loop_max), stack_used, stack_free,
      (unsigned)(avr->ramend + 1 - 0x100), data_end, resets, gps_bytes,
      hang_isr ? us(hang_isr - hang_at) : -1.0, hang_reset ? us(hang_reset - hang_at) : -1.0);
  avr_terminate(avr);
  return state == cpu_Crashed ? 1 : 0;
}
