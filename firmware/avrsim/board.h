// The robot's board around the flashed image: simavr's ATmega328P at 16 MHz running robot.elf,
// with an RFM69 on its SPI bus (chip select D10), the GPS receiver on its UART, the battery on
// ADC0 and the motor driver's pins read back. Used by the harness (harness.c) and, as
// libamz_board.so through ctypes, by the simulator (basestation/sim/flashed.py), so that the
// base station's agent can drive the very image that is flashed.
//
// Time is the emulated chip's cycles, never the host's clock: nothing happens between calls,
// and amz_board_run_until() runs the chip up to a cycle.
#ifndef AMZ_AVRSIM_BOARD_H
#define AMZ_AVRSIM_BOARD_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define AMZ_BOARD_F_CPU_HZ 16000000UL
#define AMZ_BOARD_FRAME_BYTES 66  // the RFM69's FIFO: no frame, in or out, is longer

typedef struct amz_board amz_board_t;

// The board with the image at ELF_PATH loaded and powered (battery_mv on ADC0's pin), with
// its radio module or (WITH_RADIO 0) without one, as a board whose module has failed; NULL if
// the file is not an AVR image for this chip. The caller destroys it.
amz_board_t* amz_board_create(const char* elf_path, unsigned battery_mv, int with_radio);
void amz_board_destroy(amz_board_t* board);

uint64_t amz_board_cycle(const amz_board_t* board);
// Run the chip until CYCLE (or its end: a crash, a sleep with interrupts off). Returns
// simavr's state: 1 (running) or 2 (sleeping) while it goes on.
int amz_board_run_until(amz_board_t* board, uint64_t cycle);
// One instruction, or a sleep up to the next event (a reset takes a step of its own).
int amz_board_step(amz_board_t* board);
// Pull the reset pin (RAM is left as it was, the EEPROM kept).
void amz_board_reset(amz_board_t* board);

// A frame on the air for the robot (length byte first), received at RSSI_DBM (what the
// radio's RSSI register then reads), taken into the radio's FIFO once it listens with its
// FIFO empty, in the order given. Returns 0, or -1 if it is not 1 to 66 bytes or 16 frames
// already wait.
int amz_board_air_in(amz_board_t* board, const uint8_t* frame, int length, int rssi_dbm);
// The oldest frame the image has put on the air, if any: its bytes (length byte first) into
// OUT, the cycle its transmission began at into SENT_AT; returns its length, 0 if none.
int amz_board_air_out(amz_board_t* board, uint8_t* out, int capacity, uint64_t* sent_at);
// Frames delivered to the image's radio, and sent by it, since the board was made.
unsigned long amz_board_air_counts(const amz_board_t* board, unsigned long* sent);

// Bytes from the GPS receiver, sent one byte-time apart at 115 200 baud from now on (after
// what is still being sent). Returns 0, or -1 if more than 4 KiB would wait.
int amz_board_uart_in(amz_board_t* board, const uint8_t* bytes, int length);
// The GPS receiver's sentences round and round, a burst every PERIOD_S (the harness's).
void amz_board_uart_repeat(amz_board_t* board, const uint8_t* bytes, int length, double period_s);
unsigned long amz_board_uart_sent(const amz_board_t* board);

// The battery's voltage at ADC0's pin (after the board's divider), in millivolts.
void amz_board_set_battery_mv(amz_board_t* board, unsigned millivolts);
// An input pin driven from outside: PORT 'B', 'C' or 'D', BIT 0-7, LEVEL 0 or 1.
void amz_board_set_pin(amz_board_t* board, char port, int bit, int level);

// The motor driver's inputs: PWM duty 0-255 on D9 (OC1A), enable D7, direction D8 (1 = CW).
void amz_board_motor(const amz_board_t* board, unsigned* duty, int* enable, int* direction);
// A byte of the EEPROM (-1 outside it), and one written as if before power-up (0, or -1).
int amz_board_eeprom(amz_board_t* board, unsigned address);
int amz_board_set_eeprom(amz_board_t* board, unsigned address, uint8_t value);

// The emulated chip itself, for the harness's measurements (simavr's sim_avr.h).
struct avr_t;
struct avr_t* amz_board_avr(amz_board_t* board);

#ifdef __cplusplus
}
#endif

#endif
