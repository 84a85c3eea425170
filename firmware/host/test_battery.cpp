// Battery: ADC counts through the divider, and the median filter.
#include "battery.h"
#include "harness.h"

using namespace amz;

namespace {

BatteryConfig robot_divider() {
  BatteryConfig c;
  c.vref_mv = 5000;
  c.divider_num = 15;
  c.divider_den = 1;
  c.adc_full_scale = 1024;
  return c;
}

}  // namespace

TEST(counts_convert_through_the_divider) {
  const BatteryConfig c = robot_divider();
  CHECK_EQ(battery_counts_to_10mv(0, c), 0);
  // 819 counts = 3.999 V at the pin = 59.99 V at the battery.
  CHECK_EQ(battery_counts_to_10mv(819, c), 5999);
  CHECK_EQ(battery_counts_to_10mv(820, c), 6006);  // 60.06 V: one count is 73 mV
  CHECK_EQ(battery_counts_to_10mv(1023, c), 7493);
  CHECK_EQ(battery_counts_to_10mv(5000, c), 7493);  // beyond full scale: saturates
}

TEST(fractional_divider_ratios_and_references) {
  BatteryConfig c = robot_divider();
  c.vref_mv = 1100;  // internal reference
  c.divider_num = 680;  // 670k + 10k over 10k: 68:1
  c.divider_den = 10;
  // 800 counts = 0.859375 V at the pin * 68 = 58.4375 V
  CHECK_EQ(battery_counts_to_10mv(800, c), 5844);
  c.divider_den = 0;
  CHECK_EQ(battery_counts_to_10mv(800, c), 0);
  c.divider_den = 1;
  c.divider_num = 65535;
  c.vref_mv = 65535;
  CHECK_EQ(battery_counts_to_10mv(1000, c), 0xFFFF);  // saturates, no overflow
}

TEST(median_rejects_spikes_that_a_mean_would_not) {
  // The thesis's point (figure 3.20): reading errors give huge high and low spikes.
  MedianFilter f;
  f.init(7);
  const uint16_t samples[] = {6100, 6110, 900, 6090, 65000, 6105, 6100};
  uint32_t sum = 0;
  for (size_t i = 0; i < 7; ++i) {
    f.add(samples[i]);
    sum += samples[i];
  }
  CHECK_EQ(f.median(), 6100);
  CHECK(sum / 7 > 13000);  // the mean is far off
}

TEST(median_window_slides_and_handles_partial_fill) {
  MedianFilter f;
  f.init(5);
  CHECK(f.empty());
  CHECK_EQ(f.median(), 0);
  f.add(10);
  CHECK_EQ(f.median(), 10);
  f.add(20);
  CHECK_EQ(f.median(), 15);  // even count: mean of the two middle values
  f.add(30);
  f.add(40);
  f.add(50);
  CHECK_EQ(f.median(), 30);
  for (int i = 0; i < 5; ++i) f.add(1000);
  CHECK_EQ(f.count(), 5);
  CHECK_EQ(f.median(), 1000);  // old samples left the window
  f.init(0);
  f.add(3);
  f.add(4);
  CHECK_EQ(f.median(), 4);  // window 0 is taken as 1
  f.init(200);
  for (int i = 0; i < 100; ++i) f.add(static_cast<uint16_t>(i));
  CHECK_EQ(f.count(), MedianFilter::kCapacity);
}
