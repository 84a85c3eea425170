#include "rfm69.h"

#include <Arduino.h>
#include <SPI.h>
#include <avr/pgmspace.h>

namespace {

// Register addresses (SX1231 / RFM69 datasheet, section 6).
const uint8_t REG_FIFO = 0x00;
const uint8_t REG_OPMODE = 0x01;
const uint8_t REG_DATAMODUL = 0x02;
const uint8_t REG_BITRATEMSB = 0x03;
const uint8_t REG_BITRATELSB = 0x04;
const uint8_t REG_FDEVMSB = 0x05;
const uint8_t REG_FDEVLSB = 0x06;
const uint8_t REG_FRFMSB = 0x07;
const uint8_t REG_FRFMID = 0x08;
const uint8_t REG_FRFLSB = 0x09;
const uint8_t REG_VERSION = 0x10;
const uint8_t REG_PALEVEL = 0x11;
const uint8_t REG_LNA = 0x18;
const uint8_t REG_RXBW = 0x19;
const uint8_t REG_RSSIVALUE = 0x24;
const uint8_t REG_DIOMAPPING1 = 0x25;
const uint8_t REG_DIOMAPPING2 = 0x26;
const uint8_t REG_IRQFLAGS1 = 0x27;
const uint8_t REG_IRQFLAGS2 = 0x28;
const uint8_t REG_RSSITHRESH = 0x29;
const uint8_t REG_PREAMBLEMSB = 0x2C;
const uint8_t REG_PREAMBLELSB = 0x2D;
const uint8_t REG_SYNCCONFIG = 0x2E;
const uint8_t REG_SYNCVALUE1 = 0x2F;
const uint8_t REG_SYNCVALUE2 = 0x30;
const uint8_t REG_PACKETCONFIG1 = 0x37;
const uint8_t REG_PAYLOADLENGTH = 0x38;
const uint8_t REG_NODEADRS = 0x39;
const uint8_t REG_BROADCASTADRS = 0x3A;
const uint8_t REG_FIFOTHRESH = 0x3C;
const uint8_t REG_PACKETCONFIG2 = 0x3D;
const uint8_t REG_AESKEY1 = 0x3E;
const uint8_t REG_TESTDAGC = 0x6F;

const uint8_t MODE_STANDBY = 0x04;
const uint8_t MODE_TX = 0x0C;
const uint8_t MODE_RX = 0x10;
const uint8_t MODE_MASK = 0x1C;

const uint8_t IRQ1_MODE_READY = 0x80;
const uint8_t IRQ2_FIFO_OVERRUN = 0x10;
const uint8_t IRQ2_PACKET_SENT = 0x08;
const uint8_t IRQ2_PAYLOAD_READY = 0x04;
const uint8_t PACKET2_RESTART_RX = 0x04;

const uint8_t DIO0_PAYLOAD_READY = 0x40;  // in RX
const uint8_t DIO0_PACKET_SENT = 0x00;    // in TX

const uint8_t kVersion = 0x24;
const uint8_t kSyncWord1 = 0x2D;
const uint8_t kPaHigh = 0x7F;  // PA1 + PA2, +17 dBm (RFM69HW)
const uint8_t kPaLow = 0x9F;   // PA0, +13 dBm (RFM69W)
const uint8_t kPacketConfig2 = 0x12;  // inter-packet RX delay 1, auto RX restart

// docs/protocol.md §1: the values every radio of the testbed uses.
const uint8_t kRegisters[][2] PROGMEM = {
    {REG_OPMODE, MODE_STANDBY},
    {REG_DATAMODUL, 0x00},                    // packet mode, FSK, no shaping
    {REG_BITRATEMSB, 0x02},                   // 32 MHz / 0x0240 = 55 555 bit/s
    {REG_BITRATELSB, 0x40},
    {REG_FDEVMSB, 0x03},                      // 0x0333 * 61.035 Hz = 50 kHz
    {REG_FDEVLSB, 0x33},
    {REG_FRFMSB, 0x6C},                       // 0x6C4000 * 61.035 Hz = 433.000 MHz
    {REG_FRFMID, 0x40},
    {REG_FRFLSB, 0x00},
    {REG_LNA, 0x88},                          // 200 ohm, AGC
    {REG_RXBW, 0x42},                         // 125 kHz
    {REG_DIOMAPPING1, DIO0_PAYLOAD_READY},
    {REG_DIOMAPPING2, 0x07},                  // ClkOut off
    {REG_IRQFLAGS2, IRQ2_FIFO_OVERRUN},       // clear the FIFO
    {REG_RSSITHRESH, 0xDC},                   // -110 dBm
    {REG_PREAMBLEMSB, 0x00},
    {REG_PREAMBLELSB, 0x03},                  // 3 bytes
    {REG_SYNCCONFIG, 0x88},                   // sync on, 2 bytes, no errors
    {REG_SYNCVALUE1, kSyncWord1},
    {REG_PACKETCONFIG1, 0x94},                // variable, CRC on, node or broadcast
    {REG_PAYLOADLENGTH, 66},
    {REG_BROADCASTADRS, 0xFF},
    {REG_FIFOTHRESH, 0x8F},                   // TX on FIFO not empty
    {REG_TESTDAGC, 0x30},
};

const SPISettings kSpi(4000000, MSBFIRST, SPI_MODE0);

}  // namespace

uint8_t Rfm69::read(uint8_t address) {
  SPI.beginTransaction(kSpi);
  digitalWrite(select_, LOW);
  SPI.transfer(address & 0x7F);
  const uint8_t value = SPI.transfer(0);
  digitalWrite(select_, HIGH);
  SPI.endTransaction();
  return value;
}

void Rfm69::write(uint8_t address, uint8_t value) {
  SPI.beginTransaction(kSpi);
  digitalWrite(select_, LOW);
  SPI.transfer(address | 0x80);
  SPI.transfer(value);
  digitalWrite(select_, HIGH);
  SPI.endTransaction();
}

bool Rfm69::set_mode(uint8_t mode, bool wait_ready) {
  write(REG_OPMODE, static_cast<uint8_t>((read(REG_OPMODE) & ~MODE_MASK) | mode));
  mode_ = mode;
  if (!wait_ready) return true;
  const uint32_t start = millis();
  while ((read(REG_IRQFLAGS1) & IRQ1_MODE_READY) == 0) {
    if (millis() - start > 10) return false;
  }
  return true;
}

void Rfm69::clear_fifo() { write(REG_IRQFLAGS2, IRQ2_FIFO_OVERRUN); }

void Rfm69::start_receiving() {
  // A PayloadReady left over would block reception (the FIFO is full): restart RX.
  if (read(REG_IRQFLAGS2) & IRQ2_PAYLOAD_READY) {
    write(REG_PACKETCONFIG2,
          static_cast<uint8_t>((read(REG_PACKETCONFIG2) & 0xFB) | PACKET2_RESTART_RX));
  }
  write(REG_DIOMAPPING1, DIO0_PAYLOAD_READY);
  set_mode(MODE_RX, false);
}

bool Rfm69::begin(const Settings& settings) {
  settings_ = settings;
  pinMode(select_, OUTPUT);
  digitalWrite(select_, HIGH);
  pinMode(reset_, OUTPUT);
  digitalWrite(reset_, HIGH);  // reset pulse > 100 us, then 5 ms until ready
  delayMicroseconds(200);
  digitalWrite(reset_, LOW);
  delay(6);
  SPI.begin();

  if (read(REG_VERSION) != kVersion) return false;
  // The SPI bus works both ways: a register takes what is written.
  write(REG_SYNCVALUE1, 0xAA);
  if (read(REG_SYNCVALUE1) != 0xAA) return false;
  write(REG_SYNCVALUE1, 0x55);
  if (read(REG_SYNCVALUE1) != 0x55) return false;

  for (uint8_t i = 0; i < sizeof kRegisters / sizeof kRegisters[0]; ++i) {
    write(pgm_read_byte(&kRegisters[i][0]), pgm_read_byte(&kRegisters[i][1]));
  }
  write(REG_SYNCVALUE2, settings.network);
  write(REG_NODEADRS, settings.node);
  write(REG_PALEVEL, settings.high_power ? kPaHigh : kPaLow);
  if (settings.aes_key != 0) {
    SPI.beginTransaction(kSpi);
    digitalWrite(select_, LOW);
    SPI.transfer(REG_AESKEY1 | 0x80);  // burst: the address increments
    for (uint8_t i = 0; i < 16; ++i) SPI.transfer(settings.aes_key[i]);
    digitalWrite(select_, HIGH);
    SPI.endTransaction();
    write(REG_PACKETCONFIG2, kPacketConfig2 | 0x01);
  } else {
    write(REG_PACKETCONFIG2, kPacketConfig2);
  }
  if (!set_mode(MODE_STANDBY, true)) return false;
  if (!configured()) return false;
  start_receiving();
  return true;
}

bool Rfm69::configured() {
  return read(REG_VERSION) == kVersion && read(REG_BITRATELSB) == 0x40 &&
         read(REG_FRFMSB) == 0x6C && read(REG_SYNCVALUE2) == settings_.network &&
         read(REG_NODEADRS) == settings_.node && read(REG_PACKETCONFIG1) == 0x94;
}

bool Rfm69::receive(uint8_t* frame, uint8_t* frame_len, int8_t* rssi_dbm) {
  if (mode_ != MODE_RX) start_receiving();
  if ((read(REG_IRQFLAGS2) & IRQ2_PAYLOAD_READY) == 0) return false;
  // RSSI of this packet, read before leaving RX.
  *rssi_dbm = static_cast<int8_t>(-static_cast<int16_t>(read(REG_RSSIVALUE) / 2));
  set_mode(MODE_STANDBY, true);

  SPI.beginTransaction(kSpi);
  digitalWrite(select_, LOW);
  SPI.transfer(REG_FIFO & 0x7F);
  const uint8_t len = SPI.transfer(0);
  bool ok = len >= 1 && len < kMaxFrame;
  if (ok) {
    frame[0] = len;
    for (uint8_t i = 1; i <= len; ++i) frame[i] = SPI.transfer(0);
    *frame_len = static_cast<uint8_t>(len + 1);
  }
  digitalWrite(select_, HIGH);
  SPI.endTransaction();
  if (!ok) clear_fifo();
  start_receiving();
  return ok;
}

bool Rfm69::send(const uint8_t* frame, uint8_t frame_len, void (*idle)()) {
  if (frame_len == 0 || frame_len > kMaxFrame) return false;
  set_mode(MODE_STANDBY, true);
  clear_fifo();
  SPI.beginTransaction(kSpi);
  digitalWrite(select_, LOW);
  SPI.transfer(REG_FIFO | 0x80);
  for (uint8_t i = 0; i < frame_len; ++i) SPI.transfer(frame[i]);
  digitalWrite(select_, HIGH);
  SPI.endTransaction();

  write(REG_DIOMAPPING1, DIO0_PACKET_SENT);
  set_mode(MODE_TX, false);
  const uint32_t start = millis();
  bool sent = true;
  while ((read(REG_IRQFLAGS2) & IRQ2_PACKET_SENT) == 0) {
    if (millis() - start > 30) {
      sent = false;
      break;
    }
    if (idle != 0) idle();
  }
  set_mode(MODE_STANDBY, true);
  start_receiving();
  return sent;
}
