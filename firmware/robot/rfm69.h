// A register-level driver for the HopeRF RFM69 (SX1231) in packet mode, written from the
// datasheet's register map for the settings of docs/protocol.md §1. Polls the IRQ flags
// over SPI (no interrupt handler), so it cannot stall the main loop or the watchdog.
#ifndef AMZ_RFM69_H
#define AMZ_RFM69_H

#include <stdint.h>

class Rfm69 {
 public:
  struct Settings {
    uint8_t node;            // RegNodeAdrs
    uint8_t network;         // second sync byte
    bool high_power;         // RFM69HW/HCW: PA1+PA2 on PA_BOOST; RFM69W: PA0
    const uint8_t* aes_key;  // 16 bytes, or 0 for no AES
  };

  static const uint8_t kMaxFrame = 66;

  Rfm69(uint8_t select_pin, uint8_t reset_pin) : select_(select_pin), reset_(reset_pin), mode_(0) {}

  // Reset the module, check RegVersion, write every register, enter RX. False: no radio
  // (or it did not take the configuration).
  bool begin(const Settings& settings);
  // The configuration is still in the registers (a brown-out resets the module alone).
  bool configured();
  // A frame waiting in the FIFO: copied to `frame` (length byte first), true. Non-blocking.
  bool receive(uint8_t* frame, uint8_t* frame_len, int8_t* rssi_dbm);
  // Transmit one frame (length byte first) and return to RX. `idle` runs while waiting
  // for PacketSent (at most 30 ms). False on a timeout.
  bool send(const uint8_t* frame, uint8_t frame_len, void (*idle)());

 private:
  uint8_t read(uint8_t address);
  void write(uint8_t address, uint8_t value);
  bool set_mode(uint8_t mode, bool wait_ready);
  void start_receiving();
  void clear_fifo();

  Settings settings_;
  uint8_t select_;
  uint8_t reset_;
  uint8_t mode_;
};

#endif
