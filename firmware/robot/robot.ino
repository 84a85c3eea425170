// AMazING mobile node: the robot's Arduino sketch. It only wires the portable core
// (firmware/core: frames, motion controller, GPS, battery) to the board; every safety rule
// lives in the core and is tested on the host (make -C firmware test).
//
// Safety does not depend on the radio or the base station:
//   - dead-man: no fresh command for 500 ms -> the core ramps to zero;
//   - the e-stop latch is kept in EEPROM and survives a restart;
//   - the hardware watchdog (250 ms) is reset only at the end of loop(); when it fires, its
//     interrupt cuts the motor outputs at once and the reset follows 250 ms later;
//   - the motor outputs are held off (and pulled down on the board) until setup() is done.
#include <Arduino.h>
#include <SPI.h>
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "board.h"
#include "rfm69.h"
#include "robot_app.h"
#include "robot_config.h"

#ifndef AMZ_GPS_BAUD
#define AMZ_GPS_BAUD 115200
#endif
#ifndef AMZ_RFM69_HW
#define AMZ_RFM69_HW 1  // RFM69HW/HCW; 0 for an RFM69W
#endif
#ifndef AMZ_LOCAL_STOP_ENABLED
#define AMZ_LOCAL_STOP_ENABLED 0  // 1 when a normally-closed stop loop is wired to D4
#endif
#ifndef AMZ_WHEEL_UM_PER_PULSE
#define AMZ_WHEEL_UM_PER_PULSE 0  // wheel travel per hall pulse; 0 = no wheel sensor
#endif

namespace {

const uint8_t kEepromEStop = 0;  // EEPROM address of the latch
const uint8_t kEStopLatched = 0xE5;
const uint32_t kWatchdogMagic = 0x57444F47UL;  // "WDOG"
const uint16_t kBatteryPeriodMs = 20;
const uint16_t kRadioCheckPeriodMs = 1000;

amz::RobotApp app;
Rfm69 radio(board::kRadioSelect, board::kRadioReset);
bool radio_ok = false;
bool e_stop_saved = false;
uint8_t direction_out = amz::DIR_CW;
uint32_t last_battery_ms = 0;
uint32_t last_radio_check_ms = 0;
#if AMZ_WHEEL_UM_PER_PULSE > 0
const uint16_t kWheelPeriodMs = 100;
uint32_t last_wheel_ms = 0;
volatile uint16_t wheel_pulses = 0;
#endif
#if AMZ_LOCAL_STOP_ENABLED
const uint16_t kLocalStopCloseMs = 50;
uint32_t local_stop_closed_since_ms = 0;
#endif

#ifdef AMZ_AES_KEY_HEX
static_assert(sizeof(AMZ_AES_KEY_HEX) == 33, "AES_KEY must be 32 hex digits");
uint8_t aes_key[16];
#endif

}  // namespace

// Survive the C runtime's .bss clearing: set by the watchdog interrupt, read after reset.
uint32_t watchdog_marker __attribute__((section(".noinit")));
uint8_t reset_flags __attribute__((section(".noinit")));

// Runs before the C runtime initialises anything: keep the reset cause, and stop a
// watchdog that a watchdog reset leaves running (at its shortest period).
void capture_reset_cause() __attribute__((naked, used, section(".init3")));
void capture_reset_cause() {
  reset_flags = MCUSR;
  MCUSR = 0;
  wdt_disable();
}

// The loop has been stuck for 250 ms: remove the drive now, mark the cause; the watchdog
// resets the MCU at its next timeout. Direct port writes, matching board.h (D9 = PB1
// OC1A, D7 = PD7).
ISR(WDT_vect) {
  TCCR1A &= static_cast<uint8_t>(~_BV(COM1A1));
  PORTB &= static_cast<uint8_t>(~_BV(PB1));
  PORTD &= static_cast<uint8_t>(~_BV(PD7));
  watchdog_marker = kWatchdogMagic;
}

namespace {

void motor_off() {
  analogWrite(board::kMotorPwm, 0);
  digitalWrite(board::kMotorEnable, LOW);
}

void apply_motor(const amz::MotionOutput& out) {
  if (!out.drive_enabled) {
    motor_off();
    return;
  }
  if (out.direction != direction_out) {
    // The core changes direction only at zero duty; never flip the pin under drive.
    analogWrite(board::kMotorPwm, 0);
    digitalWrite(board::kMotorDirection, out.direction == amz::DIR_CW ? HIGH : LOW);
    direction_out = out.direction;
  }
  digitalWrite(board::kMotorEnable, HIGH);
  analogWrite(board::kMotorPwm, out.duty);
}

void pump_gps() {
  const uint32_t now = millis();
  uint8_t budget = 64;  // bounded: one receive buffer's worth per call
  while (budget-- > 0 && Serial.available() > 0) {
    app.feed_gps(now, static_cast<char>(Serial.read()));
  }
}

#ifdef AMZ_AES_KEY_HEX
int8_t hex_nibble(char c) {
  if (c >= '0' && c <= '9') return static_cast<int8_t>(c - '0');
  if (c >= 'a' && c <= 'f') return static_cast<int8_t>(c - 'a' + 10);
  if (c >= 'A' && c <= 'F') return static_cast<int8_t>(c - 'A' + 10);
  return -1;
}

bool parse_aes_key() {
  const char* hex = AMZ_AES_KEY_HEX;
  for (uint8_t i = 0; i < 16; ++i) {
    const int8_t hi = hex_nibble(hex[2 * i]);
    const int8_t lo = hex_nibble(hex[2 * i + 1]);
    if (hi < 0 || lo < 0) return false;
    aes_key[i] = static_cast<uint8_t>((hi << 4) | lo);
  }
  return true;
}
#endif

bool start_radio() {
  Rfm69::Settings settings;
  settings.node = AMZ_ROBOT_NODE;
  settings.network = AMZ_NETWORK_ID;
  settings.high_power = AMZ_RFM69_HW != 0;
  settings.aes_key = 0;
#ifdef AMZ_AES_KEY_HEX
  if (!parse_aes_key()) return false;  // a bad key: no radio, so the robot stays stopped
  settings.aes_key = aes_key;
#endif
  return radio.begin(settings);
}

void poll_radio(uint32_t now) {
  if (!radio_ok) return;
  uint8_t frame[Rfm69::kMaxFrame];
  uint8_t len = 0;
  int8_t rssi = 0;
  if (!radio.receive(frame, &len, &rssi)) return;
  uint8_t reply[Rfm69::kMaxFrame];
  const size_t reply_len = app.handle_frame(now, frame, len, rssi, reply, sizeof reply);
  // Act on the frame (an e-stop above all) before spending time on the answer.
  apply_motor(app.step(millis()));
  if (reply_len > 0) radio.send(reply, static_cast<uint8_t>(reply_len), &pump_gps);
}

void check_radio(uint32_t now) {
  if (now - last_radio_check_ms < kRadioCheckPeriodMs) return;
  last_radio_check_ms = now;
  if (!radio_ok || !radio.configured()) radio_ok = start_radio();
}

void sample_battery(uint32_t now) {
  if (now - last_battery_ms < kBatteryPeriodMs) return;
  last_battery_ms = now;
  app.add_battery_sample(static_cast<uint16_t>(analogRead(board::kBatteryAdc)));
}

#if AMZ_WHEEL_UM_PER_PULSE > 0
void count_wheel_pulse() { ++wheel_pulses; }
#endif

void sample_wheel(uint32_t now) {
#if AMZ_WHEEL_UM_PER_PULSE > 0
  const uint32_t dt = now - last_wheel_ms;
  if (dt < kWheelPeriodMs) return;
  last_wheel_ms = now;
  noInterrupts();
  const uint16_t pulses = wheel_pulses;
  wheel_pulses = 0;
  interrupts();
  // um per ms = mm per s.
  const uint32_t mm_s = static_cast<uint32_t>(pulses) * AMZ_WHEEL_UM_PER_PULSE / dt;
  app.set_measured_velocity(now, static_cast<uint16_t>(mm_s > 0xFFFF ? 0xFFFF : mm_s));
#else
  (void)now;
#endif
}

void read_local_stop(uint32_t now) {
#if AMZ_LOCAL_STOP_ENABLED
  // Open loop (HIGH through the pull-up): stop at once. Closed: only once it has stayed
  // closed for a while, so contact bounce cannot clear it.
  if (digitalRead(board::kLocalStop) == HIGH) {
    app.set_local_stop(true);
    local_stop_closed_since_ms = now;
  } else if (now - local_stop_closed_since_ms >= kLocalStopCloseMs) {
    app.set_local_stop(false);
  }
#else
  (void)now;
#endif
}

void persist_e_stop() {
  const bool latched = app.e_stop_latched();
  if (latched == e_stop_saved) return;
  eeprom_update_byte(reinterpret_cast<uint8_t*>(kEepromEStop), latched ? kEStopLatched : 0x00);
  e_stop_saved = latched;
}

// Idle until the next interrupt: the millisecond timer's (every 1.024 ms), a GPS byte or a
// wheel pulse. The timers, the UART, the PWM and the watchdog run on in idle mode, so nothing
// the loop does comes later than before by more than that millisecond (a frame waits for the
// next pass to be read, as it did between passes); the chip spends the rest of its time
// asleep instead of polling. Interrupts are off from the check to the sleep instruction (the
// instruction after `sei` always runs), so a byte that arrives in between cannot be slept past.
void idle_until_interrupt() {
  set_sleep_mode(SLEEP_MODE_IDLE);
  noInterrupts();
  if (Serial.available() > 0) {
    interrupts();
    return;
  }
  sleep_enable();
  interrupts();
  sleep_cpu();
  sleep_disable();
}

}  // namespace

void setup() {
  // Outputs off before anything else.
  pinMode(board::kMotorEnable, OUTPUT);
  digitalWrite(board::kMotorEnable, LOW);
  pinMode(board::kMotorPwm, OUTPUT);
  analogWrite(board::kMotorPwm, 0);
  pinMode(board::kMotorDirection, OUTPUT);
  digitalWrite(board::kMotorDirection, HIGH);  // CW, the core's initial direction
  direction_out = amz::DIR_CW;

  pinMode(board::kRadioDio0, INPUT);
  pinMode(board::kWheelPulse, INPUT_PULLUP);
  pinMode(board::kLocalStop, INPUT_PULLUP);

  const bool watchdog_reset =
      (reset_flags & _BV(WDRF)) != 0 || watchdog_marker == kWatchdogMagic;
  watchdog_marker = 0;
  e_stop_saved =
      eeprom_read_byte(reinterpret_cast<const uint8_t*>(kEepromEStop)) == kEStopLatched;

  const uint32_t now = millis();
  app.init(amz::default_robot_config(), now, e_stop_saved, watchdog_reset);

  Serial.begin(AMZ_GPS_BAUD);
#if AMZ_WHEEL_UM_PER_PULSE > 0
  attachInterrupt(digitalPinToInterrupt(board::kWheelPulse), count_wheel_pulse, FALLING);
#endif
  radio_ok = start_radio();
  last_radio_check_ms = millis();

  wdt_enable(WDTO_250MS);
  WDTCSR |= _BV(WDIE);  // interrupt first (cuts the drive), reset at the next timeout
}

void loop() {
  idle_until_interrupt();
  const uint32_t now = millis();
  pump_gps();
  read_local_stop(now);
  poll_radio(now);
  sample_battery(now);
  sample_wheel(now);
  apply_motor(app.step(millis()));
  persist_e_stop();
  check_radio(now);
  // Only here: a loop that stops coming round lets the watchdog cut the drive and reset.
  wdt_reset();
  WDTCSR |= _BV(WDIE);  // the interrupt enable clears itself each time the interrupt runs
}
