// Pin map of the robot's Arduino Nano (ATmega328P, 5 V, 16 MHz). docs/firmware.md has the
// wiring table; the thesis lists only the base station's Raspberry Pi pins.
#ifndef AMZ_BOARD_H
#define AMZ_BOARD_H

#include <stdint.h>

namespace board {

// RFM69 on the hardware SPI (D11 MOSI, D12 MISO, D13 SCK) through a 3.3 V level shifter.
const uint8_t kRadioSelect = 10;  // NSS; also the AVR's SS, which must be an output
const uint8_t kRadioDio0 = 2;     // PayloadReady / PacketSent (INT0); polled, not interrupt
const uint8_t kRadioReset = A1;   // RFM69 RESET, active high

// Motor driver (throttle through an RC filter, direction, enable).
const uint8_t kMotorPwm = 9;      // Timer1 PWM, 490 Hz; pulled down on the board
const uint8_t kMotorDirection = 8;  // HIGH = CW
const uint8_t kMotorEnable = 7;   // HIGH = drive allowed; pulled down: off in reset

// Sensors.
const uint8_t kBatteryAdc = A0;   // battery through the 15:1 divider
const uint8_t kWheelPulse = 3;    // optional wheel hall sensor (INT1)
const uint8_t kLocalStop = 4;     // optional normally-closed stop loop to GND; open = stop
// GPS: hardware Serial, D0 = RX from the receiver's TX (D1 to its RX for configuration).

}  // namespace board

#endif
