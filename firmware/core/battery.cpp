#include "battery.h"

namespace amz {

uint16_t battery_counts_to_10mv(uint16_t counts, const BatteryConfig& c) {
  if (c.divider_den == 0 || c.adc_full_scale == 0) return 0;
  if (counts >= c.adc_full_scale) counts = static_cast<uint16_t>(c.adc_full_scale - 1);
  // pin mV = counts * vref / full_scale, kept as quotient and remainder so that the
  // multiplication by the divider ratio neither overflows 32 bits nor loses precision.
  const uint32_t a = static_cast<uint32_t>(counts) * c.vref_mv;
  const uint32_t q = a / c.adc_full_scale;  // <= vref_mv
  const uint32_t r = a % c.adc_full_scale;
  const uint32_t whole = q * c.divider_num;
  const uint32_t part = (r * c.divider_num) / c.adc_full_scale;
  if (whole > 0xFFFFFFFFUL - part) return 0xFFFF;
  const uint32_t mv_times_den = whole + part;
  const uint32_t divisor = static_cast<uint32_t>(c.divider_den) * 10UL;
  const uint32_t v10mv = mv_times_den / divisor + ((mv_times_den % divisor) * 2 >= divisor);
  return v10mv > 0xFFFFUL ? 0xFFFF : static_cast<uint16_t>(v10mv);
}

void MedianFilter::init(uint8_t window) {
  if (window < 1) window = 1;
  if (window > kCapacity) window = kCapacity;
  window_ = window;
  count_ = 0;
  next_ = 0;
}

void MedianFilter::add(uint16_t sample) {
  samples_[next_] = sample;
  next_ = static_cast<uint8_t>(next_ + 1 == window_ ? 0 : next_ + 1);
  if (count_ < window_) ++count_;
}

uint16_t MedianFilter::median() const {
  if (count_ == 0) return 0;
  uint16_t sorted[kCapacity];
  for (uint8_t i = 0; i < count_; ++i) {  // insertion sort: at most 15 values
    const uint16_t v = samples_[i];
    uint8_t j = i;
    while (j > 0 && sorted[j - 1] > v) {
      sorted[j] = sorted[j - 1];
      --j;
    }
    sorted[j] = v;
  }
  const uint8_t mid = static_cast<uint8_t>(count_ / 2);
  if (count_ & 1) return sorted[mid];
  return static_cast<uint16_t>((static_cast<uint32_t>(sorted[mid - 1]) + sorted[mid]) / 2);
}

}  // namespace amz
