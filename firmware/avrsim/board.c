// The robot's board around the flashed image (board.h): simavr's ATmega328P with an RFM69 on
// its SPI bus, the GPS receiver on its UART, the battery on ADC0 and the motor pins.
#include "board.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <avr_adc.h>
#include <avr_eeprom.h>
#include <avr_ioport.h>
#include <avr_spi.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>

#define GPS_BAUD 115200UL
#define UART_QUEUE_BYTES 4096
#define AIR_QUEUE_FRAMES 16

// The emulator's "sleep" keeps it in step with the host's clock: here emulated time runs as
// fast as the host can, and only cycles count.
static void no_wall_clock(avr_t* avr, avr_cycle_count_t how_long) {
  (void)avr;
  (void)how_long;
}

// simavr's own messages: only its errors (an image that crashes says why), on stderr.
static void errors_only(avr_t* avr, const int level, const char* format, va_list ap) {
  (void)avr;
  if (level <= LOG_ERROR) vfprintf(stderr, format, ap);
}

// --- The RFM69 on the SPI bus ------------------------------------------------------------------
// Registers, FIFO, modes and IRQ flags as the robot's driver (firmware/robot/rfm69.cpp) uses
// them; a packet is on the air for as long as its bytes take at the driver's bit rate.

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
#define RF_BITRATE_BPS 55555.0  // what the driver sets (32 MHz / 0x0240)
#define RF_OVERHEAD_BYTES 7     // preamble 3, sync 2, CRC 2

typedef struct {
  uint8_t length;
  uint8_t bytes[AMZ_BOARD_FRAME_BYTES];
  avr_cycle_count_t at;
  uint8_t rssi_value;  // RegRssiValue while it is received: -2 x dBm
} frame_t;

typedef struct {
  frame_t frames[AIR_QUEUE_FRAMES];
  int head, count;
} frame_queue_t;

static int queue_push(frame_queue_t* q, const uint8_t* bytes, int length, avr_cycle_count_t at,
                      uint8_t rssi_value) {
  if (q->count == AIR_QUEUE_FRAMES) return -1;
  frame_t* f = &q->frames[(q->head + q->count) % AIR_QUEUE_FRAMES];
  f->length = (uint8_t)length;
  memcpy(f->bytes, bytes, (size_t)length);
  f->at = at;
  f->rssi_value = rssi_value;
  ++q->count;
  return 0;
}

static const frame_t* queue_pop(frame_queue_t* q) {
  if (q->count == 0) return NULL;
  const frame_t* f = &q->frames[q->head];
  q->head = (q->head + 1) % AIR_QUEUE_FRAMES;
  --q->count;
  return f;
}

typedef struct {
  avr_t* avr;
  avr_irq_t* spi_in;
  uint8_t reg[0x80];
  uint8_t fifo[AMZ_BOARD_FRAME_BYTES];
  int fifo_len, fifo_pos;
  int selected, byte_index, writing;
  uint8_t address;
  int payload_ready;
  uint8_t rssi_value;         // what RegRssiValue reads: the last frame's strength
  avr_cycle_count_t sent_at;  // PacketSent from this cycle on, while in TX (0: not sending)
  frame_queue_t incoming, outgoing;
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
    // On the air now; sent once its bytes have crossed at the bit rate. A reader that has not
    // taken the oldest of a full queue loses it, not the newest.
    const double air_s = (r->fifo_len + RF_OVERHEAD_BYTES) * 8.0 / RF_BITRATE_BPS;
    if (r->outgoing.count == AIR_QUEUE_FRAMES) queue_pop(&r->outgoing);
    queue_push(&r->outgoing, r->fifo, r->fifo_len, r->avr->cycle, 0);
    r->sent_at = r->avr->cycle + (avr_cycle_count_t)(air_s * AMZ_BOARD_F_CPU_HZ) + 1;
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
      return r->rssi_value;
    default:
      return r->reg[address & 0x7F];
  }
}

static void rf_write(rfm69_t* r, uint8_t address, uint8_t value) {
  switch (address) {
    case RF_FIFO:
      if (r->fifo_len < AMZ_BOARD_FRAME_BYTES) r->fifo[r->fifo_len++] = value;
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
    if (r->byte_index == 0) {
      r->address = value & 0x7F;
      r->writing = (value & 0x80) != 0;
    } else {
      if (r->writing) {
        rf_write(r, r->address, value);
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

// The next frame on the air into a listening radio with an empty FIFO.
static void rf_deliver(rfm69_t* r) {
  if (r->incoming.count == 0) return;
  if ((r->reg[RF_OPMODE] & RF_MODE_MASK) != RF_MODE_RX || r->payload_ready) return;
  const frame_t* frame = queue_pop(&r->incoming);
  memcpy(r->fifo, frame->bytes, frame->length);
  r->fifo_len = frame->length;
  r->fifo_pos = 0;
  r->payload_ready = 1;
  r->rssi_value = frame->rssi_value;
  ++r->delivered;
}

static void rf_attach(rfm69_t* r, avr_t* avr) {
  memset(r, 0, sizeof *r);
  r->avr = avr;
  r->reg[RF_VERSION] = 0x24;
  r->reg[RF_OPMODE] = 0x04;
  r->rssi_value = 120;  // -60 dBm until a frame says otherwise
  r->spi_in = avr_io_getirq(avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_INPUT);
  avr_register_io_write(avr, SPDR_DATA, rf_spi_byte, r);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 2), rf_select, r);
}

// --- The GPS receiver on the UART --------------------------------------------------------------
// Each byte at its own cycle (a cycle timer), so that a byte wakes a sleeping chip when it
// arrives, as the UART's receive interrupt does on the board.

typedef struct {
  avr_irq_t* uart_in;
  uint8_t queue[UART_QUEUE_BYTES];
  size_t head, count;
  const uint8_t* repeat;  // sentences sent round and round, a burst every burst_cycles
  size_t repeat_len, repeat_pos;
  avr_cycle_count_t byte_cycles, burst_cycles, burst_start;
  unsigned long sent;
} uart_feed_t;

static avr_cycle_count_t uart_byte(avr_t* avr, avr_cycle_count_t when, void* param) {
  (void)avr;
  uart_feed_t* u = (uart_feed_t*)param;
  if (u->repeat != NULL) {
    const uint8_t byte = u->repeat[u->repeat_pos];
    avr_raise_irq(u->uart_in, byte);
    ++u->sent;
    u->repeat_pos = (u->repeat_pos + 1) % u->repeat_len;
    if (byte != '\n') return when + u->byte_cycles;
    u->burst_start += u->burst_cycles;
    return u->burst_start > when ? u->burst_start : when + u->byte_cycles;
  }
  if (u->count == 0) return 0;
  avr_raise_irq(u->uart_in, u->queue[u->head]);
  ++u->sent;
  u->head = (u->head + 1) % UART_QUEUE_BYTES;
  --u->count;
  return u->count > 0 ? when + u->byte_cycles : 0;
}

// A reset empties simavr's timers: the receiver, which has its own power, goes on.
static void uart_keep_sending(avr_t* avr, uart_feed_t* u) {
  if ((u->repeat != NULL || u->count > 0) && avr_cycle_timer_status(avr, uart_byte, u) == 0) {
    avr_cycle_timer_register(avr, u->byte_cycles, uart_byte, u);
  }
}

// --- The board ---------------------------------------------------------------------------------

struct amz_board {
  avr_t* avr;
  elf_firmware_t firmware;
  rfm69_t radio;
  uart_feed_t uart;
  avr_irq_t* adc0;
  int state;
};

amz_board_t* amz_board_create(const char* elf_path, unsigned battery_mv, int with_radio) {
  avr_global_logger_set(errors_only);
  amz_board_t* b = (amz_board_t*)calloc(1, sizeof *b);
  if (b == NULL) return NULL;
  if (elf_read_firmware(elf_path, &b->firmware) != 0) {
    free(b);
    return NULL;
  }
  b->avr = avr_make_mcu_by_name("atmega328p");
  if (b->avr == NULL) {
    free(b);
    return NULL;
  }
  avr_t* avr = b->avr;
  avr_init(avr);
  avr->frequency = AMZ_BOARD_F_CPU_HZ;
  avr->vcc = avr->avcc = avr->aref = 5000;  // the Nano's 5 V: the ADC's reference is AVCC
  avr->log = LOG_ERROR;
  avr->sleep = no_wall_clock;
  avr_load_firmware(avr, &b->firmware);
  if (with_radio) rf_attach(&b->radio, avr);
  b->uart.uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  b->uart.byte_cycles = AMZ_BOARD_F_CPU_HZ * 10 / GPS_BAUD;  // start, 8 data, stop
  b->adc0 = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0);
  avr_raise_irq(b->adc0, battery_mv);
  b->state = cpu_Running;
  return b;
}

void amz_board_destroy(amz_board_t* b) {
  if (b == NULL) return;
  avr_terminate(b->avr);
  free(b);
}

uint64_t amz_board_cycle(const amz_board_t* b) { return b->avr->cycle; }

int amz_board_step(amz_board_t* b) {
  avr_t* avr = b->avr;
  if (b->state == cpu_Done || b->state == cpu_Crashed) return b->state;
  if (avr->pc == 0) uart_keep_sending(avr, &b->uart);  // the chip (re)starts
  rf_deliver(&b->radio);
  b->state = avr_run(avr);
  return b->state;
}

int amz_board_run_until(amz_board_t* b, uint64_t cycle) {
  while (b->avr->cycle < cycle && b->state != cpu_Done && b->state != cpu_Crashed) {
    amz_board_step(b);
  }
  return b->state;
}

void amz_board_reset(amz_board_t* b) {
  avr_reset(b->avr);
  uart_keep_sending(b->avr, &b->uart);
}

int amz_board_air_in(amz_board_t* b, const uint8_t* frame, int length, int rssi_dbm) {
  if (length < 1 || length > AMZ_BOARD_FRAME_BYTES) return -1;
  const int value = -2 * (rssi_dbm > 0 ? 0 : rssi_dbm < -127 ? -127 : rssi_dbm);
  return queue_push(&b->radio.incoming, frame, length, b->avr->cycle, (uint8_t)value);
}

int amz_board_air_out(amz_board_t* b, uint8_t* out, int capacity, uint64_t* sent_at) {
  const frame_t* f = queue_pop(&b->radio.outgoing);
  if (f == NULL) return 0;
  const int n = f->length < capacity ? f->length : capacity;
  memcpy(out, f->bytes, (size_t)n);
  if (sent_at != NULL) *sent_at = f->at;
  return n;
}

unsigned long amz_board_air_counts(const amz_board_t* b, unsigned long* sent) {
  if (sent != NULL) *sent = b->radio.sent;
  return b->radio.delivered;
}

int amz_board_uart_in(amz_board_t* b, const uint8_t* bytes, int length) {
  uart_feed_t* u = &b->uart;
  if (length < 0 || u->count + (size_t)length > UART_QUEUE_BYTES) return -1;
  for (int i = 0; i < length; ++i) u->queue[(u->head + u->count++) % UART_QUEUE_BYTES] = bytes[i];
  uart_keep_sending(b->avr, u);
  return 0;
}

void amz_board_uart_repeat(amz_board_t* b, const uint8_t* bytes, int length, double period_s) {
  uart_feed_t* u = &b->uart;
  u->repeat = bytes;
  u->repeat_len = (size_t)length;
  u->repeat_pos = 0;
  u->burst_cycles = (avr_cycle_count_t)(period_s * AMZ_BOARD_F_CPU_HZ);
  u->burst_start = b->avr->cycle;
  uart_keep_sending(b->avr, u);
}

unsigned long amz_board_uart_sent(const amz_board_t* b) { return b->uart.sent; }

void amz_board_set_battery_mv(amz_board_t* b, unsigned millivolts) {
  avr_raise_irq(b->adc0, millivolts);
}

void amz_board_set_pin(amz_board_t* b, char port, int bit, int level) {
  avr_raise_irq(avr_io_getirq(b->avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit), level ? 1 : 0);
}

void amz_board_motor(const amz_board_t* b, unsigned* duty, int* enable, int* direction) {
  const uint8_t* data = b->avr->data;
  const uint8_t tccr1a = data[0x80], ocr1al = data[0x88];
  const uint8_t portb = data[0x25], portd = data[0x2B];
  const int pwm_on = (tccr1a & 0x80) != 0;  // COM1A1: the pin follows the timer
  *duty = pwm_on ? ocr1al : ((portb & 0x02) ? 255u : 0u);
  *enable = (portd & 0x80) != 0;
  *direction = (portb & 0x01) != 0;
}

int amz_board_eeprom(amz_board_t* b, unsigned address) {
  avr_eeprom_desc_t eeprom = {.ee = NULL, .offset = 0, .size = 1};
  avr_ioctl(b->avr, AVR_IOCTL_EEPROM_GET, &eeprom);  // points eeprom.ee at the chip's EEPROM
  if (eeprom.ee == NULL || address > b->avr->e2end) return -1;
  return eeprom.ee[address];
}

int amz_board_set_eeprom(amz_board_t* b, unsigned address, uint8_t value) {
  if (address > b->avr->e2end) return -1;
  avr_eeprom_desc_t eeprom = {.ee = &value, .offset = (uint16_t)address, .size = 1};
  return avr_ioctl(b->avr, AVR_IOCTL_EEPROM_SET, &eeprom) == 0 ? 0 : -1;
}

avr_t* amz_board_avr(amz_board_t* b) { return b->avr; }
