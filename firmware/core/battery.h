// Battery voltage: ADC counts through the resistor divider, and a median filter that
// rejects the reading spikes the thesis saw (its figure 3.20) where a mean would not.
#ifndef AMZ_BATTERY_H
#define AMZ_BATTERY_H

#include <stdint.h>

namespace amz {

struct BatteryConfig {
  uint16_t vref_mv;         // ADC reference (AVcc 5000 mV, or the internal 1100 mV)
  uint16_t divider_num;     // battery voltage = pin voltage * divider_num / divider_den
  uint16_t divider_den;     //   e.g. 140 kOhm over 10 kOhm: 15 / 1
  uint16_t adc_full_scale;  // 1024 for the ATmega328P's 10-bit ADC
};

// Battery voltage in 10 mV units, rounded, saturating at 65535. Counts at or above the full
// scale are read as full scale - 1; a zero denominator or full scale gives 0.
uint16_t battery_counts_to_10mv(uint16_t counts, const BatteryConfig& config);

// Median over the last `window` samples (1..kCapacity; odd windows give a true median,
// an even count averages the two middle values).
class MedianFilter {
 public:
  static const uint8_t kCapacity = 15;

  MedianFilter() : window_(1), count_(0), next_(0) {}
  void init(uint8_t window);
  void add(uint16_t sample);
  uint8_t count() const { return count_; }
  bool empty() const { return count_ == 0; }
  uint16_t median() const;  // 0 when empty

 private:
  uint16_t samples_[kCapacity];
  uint8_t window_;
  uint8_t count_;
  uint8_t next_;
};

}  // namespace amz

#endif
