// The flashed image, executed: runs the very robot.elf that `make firmware` builds on simavr's
// emulated ATmega328P at 16 MHz, with the board's inputs (GPS sentences on the UART at their
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
#include <sim_elf.h>
#include <avr_adc.h>
#include <avr_eeprom.h>
#include <avr_ioport.h>
#include <avr_spi.h>
#include <avr_uart.h>

#define F_CPU_HZ 16000000UL
#define GPS_BAUD 115200UL
#define GPS_PERIOD_S 0.1
#define BATTERY_PIN_MV 4000  // 60 V (the simulator's full battery) through the 15:1 divider
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

// --- The RFM69 on the SPI bus ------------------------------------------------------------------

#define RF_FIFO 0x00
#define RF_OPMODE 0x01
#define RF_VERSION 0x10
#define RF_RSSIVALUE 0x24
#define RF_IRQFLAGS1 0x27
#define RF_IRQFLAGS2 0x28
#define RF_PACKETCONFIG2 0x3D
#define RF_MODE_MASK 0x1C
#define RF_MODE_TX 0x0C
#define RF_MODE_RX 0x10
#define RF_FIFO_BYTES 66
#define RF_BITRATE_BPS 55555.0  // what the driver sets (32 MHz / 0x0240)
#define RF_OVERHEAD_BYTES 7     // preamble 3, sync 2, CRC 2
#define MAX_AIR_FRAMES 4096

typedef struct {
  double at_s;
  uint8_t len;
  uint8_t bytes[RF_FIFO_BYTES];
} air_frame_t;

typedef struct {
  avr_t* avr;
  avr_irq_t* spi_in;
  uint8_t reg[0x80];
  uint8_t fifo[RF_FIFO_BYTES];
  int fifo_len, fifo_pos;
  int selected, byte_index, writing;
  uint8_t address;
  int payload_ready;
  avr_cycle_count_t sent_at;  // PacketSent from this cycle on, while in TX (0: not sending)
  air_frame_t* air;
  int air_count, air_next;
  unsigned long sent, delivered;
} rfm69_t;

static void rf_clear_fifo(rfm69_t* r) {
  r->fifo_len = r->fifo_pos = 0;
  r->payload_ready = 0;
}

static void rf_set_mode(rfm69_t* r, uint8_t mode) {
  const uint8_t was = r->reg[RF_OPMODE] & RF_MODE_MASK;
  if (was == RF_MODE_TX && mode != RF_MODE_TX) {
    r->sent_at = 0;
    rf_clear_fifo(r);
  }
  if (mode == RF_MODE_TX && was != RF_MODE_TX && r->fifo_len > 0) {
    // On the air: printed now, sent once its bytes have crossed at the bit rate.
    const double air_s = (r->fifo_len + RF_OVERHEAD_BYTES) * 8.0 / RF_BITRATE_BPS;
    printf("tx %.6f ", (double)r->avr->cycle / F_CPU_HZ);
    for (int i = 0; i < r->fifo_len; ++i) printf("%02x", r->fifo[i]);
    printf("\n");
    r->sent_at = r->avr->cycle + (avr_cycle_count_t)(air_s * F_CPU_HZ) + 1;
    ++r->sent;
  }
}

static uint8_t rf_read(rfm69_t* r, uint8_t address) {
  switch (address) {
    case RF_FIFO: {
      const uint8_t value = r->fifo_pos < r->fifo_len ? r->fifo[r->fifo_pos++] : 0;
      if (r->fifo_pos >= r->fifo_len) r->payload_ready = 0;
      return value;
    }
    case RF_IRQFLAGS1:
      return 0x80;  // ModeReady: every mode change is immediate here
    case RF_IRQFLAGS2:
      return (uint8_t)((r->fifo_pos < r->fifo_len ? 0x40 : 0) | (r->payload_ready ? 0x04 : 0) |
                       (r->sent_at && r->avr->cycle >= r->sent_at ? 0x08 : 0));
    case RF_RSSIVALUE:
      return 120;  // -60 dBm
    default:
      return r->reg[address & 0x7F];
  }
}

static void rf_write(rfm69_t* r, uint8_t address, uint8_t value) {
  switch (address) {
    case RF_FIFO:
      if (r->fifo_len < RF_FIFO_BYTES) r->fifo[r->fifo_len++] = value;
      return;
    case RF_OPMODE:
      rf_set_mode(r, value & RF_MODE_MASK);
      r->reg[RF_OPMODE] = value;
      return;
    case RF_IRQFLAGS2:
      if (value & 0x10) rf_clear_fifo(r);  // FifoOverrun written: the FIFO is emptied
      return;
    case RF_PACKETCONFIG2:
      if (value & 0x04) rf_clear_fifo(r);  // RestartRx
      r->reg[address] = value & (uint8_t)~0x04;
      return;
    case RF_VERSION:
      return;
    default:
      r->reg[address & 0x7F] = value;
  }
}

// A byte the MCU wrote to SPDR: the chip's byte is shifted back in the same transfer. Taken
// from the register write itself, not from simavr's SPI output: Debian's simavr 1.6 completes
// a transfer 100 us after the write whatever the SPI clock, fifty times the 2 us a byte takes
// at the sketch's 4 MHz, which would make every radio exchange look that much slower.
#define SPCR_DATA 0x4C
#define SPDR_DATA 0x4E
#define SPCR_SPE 0x40
#define SPCR_MSTR 0x10

static void rf_spi_byte(struct avr_t* avr, avr_io_addr_t addr, uint8_t value, void* param) {
  (void)addr;
  rfm69_t* r = (rfm69_t*)param;
  if ((avr->data[SPCR_DATA] & (SPCR_SPE | SPCR_MSTR)) != (SPCR_SPE | SPCR_MSTR)) return;
  uint8_t reply = 0;
  if (r->selected) {
    const uint8_t byte = (uint8_t)value;
    if (r->byte_index == 0) {
      r->address = byte & 0x7F;
      r->writing = (byte & 0x80) != 0;
    } else {
      if (r->writing) {
        rf_write(r, r->address, byte);
      } else {
        reply = rf_read(r, r->address);
      }
      if (r->address != RF_FIFO) r->address = (uint8_t)((r->address + 1) & 0x7F);  // burst
    }
    ++r->byte_index;
  }
  avr_raise_irq(r->spi_in, reply);
}

static void rf_select(avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  rfm69_t* r = (rfm69_t*)param;
  r->selected = value == 0;
  r->byte_index = 0;
}

// The next frame on the air, once due, into a listening radio with an empty FIFO.
static void rf_deliver(rfm69_t* r) {
  if (r->air_next >= r->air_count) return;
  const air_frame_t* frame = &r->air[r->air_next];
  if ((double)r->avr->cycle < frame->at_s * F_CPU_HZ) return;
  if ((r->reg[RF_OPMODE] & RF_MODE_MASK) != RF_MODE_RX || r->payload_ready) return;
  memcpy(r->fifo, frame->bytes, frame->len);
  r->fifo_len = frame->len;
  r->fifo_pos = 0;
  r->payload_ready = 1;
  ++r->air_next;
  ++r->delivered;
}

static int read_air(const char* path, air_frame_t* out, int cap) {
  FILE* f = fopen(path, "r");
  if (!f) {
    perror(path);
    exit(2);
  }
  int n = 0;
  char hex[2 * RF_FIFO_BYTES + 2];
  double at_s;
  while (n < cap && fscanf(f, "%lf %133s", &at_s, hex) == 2) {
    const size_t digits = strlen(hex);
    if (digits % 2 != 0 || digits / 2 > RF_FIFO_BYTES || digits == 0) {
      fprintf(stderr, "%s: frame %d is not 1-%d bytes of hex\n", path, n + 1, RF_FIFO_BYTES);
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

static void rf_attach(rfm69_t* r, avr_t* avr, air_frame_t* air, int air_count) {
  memset(r, 0, sizeof *r);
  r->avr = avr;
  r->air = air;
  r->air_count = air_count;
  r->reg[RF_VERSION] = 0x24;
  r->reg[RF_OPMODE] = 0x04;
  r->spi_in = avr_io_getirq(avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_INPUT);
  avr_register_io_write(avr, SPDR_DATA, rf_spi_byte, r);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 2), rf_select, r);
}

// The motor outputs as the board's driver sees them: PWM on D9 (OC1A), enable D7, direction D8.
static void print_motor(avr_t* avr) {
  const uint8_t tccr1a = avr->data[0x80], ocr1al = avr->data[0x88];
  const uint8_t portb = avr->data[0x25], portd = avr->data[0x2B];
  const int pwm_on = (tccr1a & 0x80) != 0;  // COM1A1: the pin follows the timer
  const unsigned duty = pwm_on ? ocr1al : ((portb & 0x02) ? 255u : 0u);
  printf("motor %.6f %u %d %d\n", (double)avr->cycle / F_CPU_HZ, duty, (portd & 0x80) != 0,
         (portb & 0x01) != 0);
}

// The GPS receiver on the UART: one sentence burst every GPS_PERIOD_S, its bytes one byte-time
// apart, each at its own cycle (a cycle timer), so that a byte wakes a sleeping chip when it
// arrives, as the UART's receive interrupt does on the board.
typedef struct {
  avr_irq_t* uart_in;
  const uint8_t* bytes;
  size_t len, pos, sent;
  avr_cycle_count_t byte_cycles, burst_cycles, burst_start;
} gps_feed_t;

static avr_cycle_count_t gps_byte(avr_t* avr, avr_cycle_count_t when, void* param) {
  (void)avr;
  gps_feed_t* g = (gps_feed_t*)param;
  const uint8_t byte = g->bytes[g->pos];
  avr_raise_irq(g->uart_in, byte);
  ++g->sent;
  g->pos = (g->pos + 1) % g->len;
  if (byte != '\n') return when + g->byte_cycles;
  g->burst_start += g->burst_cycles;
  return g->burst_start > when ? g->burst_start : when + g->byte_cycles;
}

// A reset empties simavr's timers: the receiver, which has its own power, goes on.
static void gps_keep_sending(avr_t* avr, gps_feed_t* g) {
  if (avr_cycle_timer_status(avr, gps_byte, g) == 0) {
    avr_cycle_timer_register(avr, g->byte_cycles, gps_byte, g);
  }
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
  avr->vcc = avr->avcc = avr->aref = 5000;  // the Nano's 5 V: the ADC's reference is AVCC
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
  static air_frame_t air[MAX_AIR_FRAMES];
  static rfm69_t radio;
  const int with_radio = radio_path != NULL;
  if (with_radio) rf_attach(&radio, avr, air, read_air(radio_path, air, MAX_AIR_FRAMES));
  const avr_cycle_count_t motor_every = F_CPU_HZ / 100;  // 10 ms
  avr_cycle_count_t next_motor = 0;

  const avr_cycle_count_t end = (avr_cycle_count_t)(seconds * F_CPU_HZ);
  static gps_feed_t gps_feed;
  gps_feed.uart_in = uart_in;
  gps_feed.bytes = gps;
  gps_feed.len = gps_len;
  gps_feed.byte_cycles = F_CPU_HZ * 10 / GPS_BAUD;  // start, 8 data, stop
  gps_feed.burst_cycles = (avr_cycle_count_t)(GPS_PERIOD_S * F_CPU_HZ);
  gps_keep_sending(avr, &gps_feed);

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
      gps_keep_sending(avr, &gps_feed);
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
      avr_reset(avr);
      gps_keep_sending(avr, &gps_feed);
      continue;
    }
    if (with_radio) {
      rf_deliver(&radio);
      if (avr->cycle >= next_motor) {
        print_motor(avr);
        next_motor += motor_every;
      }
    }
    const avr_cycle_count_t before = avr->cycle;
    const int sleeping = avr->state == cpu_Sleeping;
    state = avr_run(avr);
    if (sleeping) slept += avr->cycle - before;
  }

  uint32_t deepest = (uint32_t)avr->ramend + 1;
  for (uint32_t a = data_end; a <= avr->ramend; ++a) {
    if (avr->data[a] != PAINT) {
      deepest = a;
      break;
    }
  }
  avr_eeprom_desc_t eeprom = {.ee = NULL, .offset = 0, .size = 1};
  avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &eeprom);  // points eeprom.ee at the chip's EEPROM
  const int eeprom0 = eeprom.ee != NULL ? eeprom.ee[0] : -1;
  const unsigned stack_used = (unsigned)(avr->ramend + 1 - deepest);
  const unsigned stack_free = deepest - data_end;
  printf(
      "{\"emulated_s\": %.3f, \"state\": %d, \"boot_us\": %.1f, \"passes\": %lu, "
      "\"loop_mean_us\": %.1f, \"loop_max_us\": %.1f, \"stack_used_bytes\": %u, "
      "\"stack_free_bytes\": %u, \"ram_bytes\": %u, \"data_end\": %u, \"resets\": %u, "
      "\"gps_bytes\": %zu, \"hang_to_isr_us\": %.1f, \"hang_to_reset_us\": %.1f, "
      "\"hung_at_s\": %.6f, \"radio_received\": %lu, \"radio_sent\": %lu, "
      "\"eeprom0\": %d, \"asleep_share\": %.3f}\n",
      (double)avr->cycle / F_CPU_HZ, state, us(boot), passes,
      passes ? us(loop_sum) / (double)passes : 0.0, us(loop_max), stack_used, stack_free,
      (unsigned)(avr->ramend + 1 - 0x100), data_end, resets, gps_feed.sent,
      hang_isr ? us(hang_isr - hang_at) : -1.0, hang_reset ? us(hang_reset - hang_at) : -1.0,
      hung ? (double)hang_at / F_CPU_HZ : -1.0, radio.delivered, radio.sent, eeprom0,
      avr->cycle ? (double)slept / (double)avr->cycle : 0.0);
  avr_terminate(avr);
  return state == cpu_Crashed ? 1 : 0;
}
