// The robot's compiled-in configuration. Every value can be overridden at build time
// (-DAMZ_...=value). The hard limits cannot be exceeded by a config frame from the radio.
#ifndef AMZ_ROBOT_CONFIG_H
#define AMZ_ROBOT_CONFIG_H

// The build identifier the robot reports in its identity frame (docs/protocol.md §2.6):
// printable ASCII, at most 16 characters. The Makefiles set it from the last commit of the
// firmware's sources (`make -C firmware hex AMZ_BUILD_ID=...` names a build by hand).
#ifndef AMZ_BUILD_ID
#define AMZ_BUILD_ID "unversioned"
#endif

// Radio (docs/protocol.md §1).
#ifndef AMZ_ROBOT_NODE
#define AMZ_ROBOT_NODE 2
#endif
#ifndef AMZ_BASE_NODE
#define AMZ_BASE_NODE 1
#endif
#ifndef AMZ_NETWORK_ID
#define AMZ_NETWORK_ID 100
#endif

// Motion. Defaults until the base station sends a config frame.
#ifndef AMZ_MAX_VELOCITY_MM_S
#define AMZ_MAX_VELOCITY_MM_S 2000
#endif
#ifndef AMZ_ACCEL_MM_S2
#define AMZ_ACCEL_MM_S2 250
#endif
// Hard limits: a config frame is clamped into these.
#ifndef AMZ_HARD_MAX_VELOCITY_MM_S
#define AMZ_HARD_MAX_VELOCITY_MM_S 4000
#endif
#ifndef AMZ_ACCEL_MIN_MM_S2
#define AMZ_ACCEL_MIN_MM_S2 50
#endif
#ifndef AMZ_ACCEL_MAX_MM_S2
#define AMZ_ACCEL_MAX_MM_S2 1000
#endif
// Failsafe stops (dead-man, time-to-live) decelerate at least this hard.
#ifndef AMZ_STOP_DECEL_MM_S2
#define AMZ_STOP_DECEL_MM_S2 500
#endif
#ifndef AMZ_DEAD_MAN_MS
#define AMZ_DEAD_MAN_MS 500
#endif
// Longer than the drive's lag: the simulator showed the body still rolling at 32 mm/s when
// the pin flipped after 250 ms (and overshooting the ramp after); at 700 ms it is at rest.
#ifndef AMZ_REVERSE_DWELL_MS
#define AMZ_REVERSE_DWELL_MS 700
#endif
// Motor drive: duty AMZ_DUTY_MAX gives AMZ_FULL_SCALE_MM_S (the thesis: close to 30 km/h).
#ifndef AMZ_FULL_SCALE_MM_S
#define AMZ_FULL_SCALE_MM_S 8333
#endif
#ifndef AMZ_DUTY_MIN
#define AMZ_DUTY_MIN 0
#endif
#ifndef AMZ_DUTY_MAX
#define AMZ_DUTY_MAX 255
#endif

// Battery: five 12 V batteries (about 60 V) through a 15:1 divider (140k over 10k) on a
// 5 V reference: 75 V full scale.
#ifndef AMZ_BATTERY_VREF_MV
#define AMZ_BATTERY_VREF_MV 5000
#endif
#ifndef AMZ_BATTERY_DIVIDER_NUM
#define AMZ_BATTERY_DIVIDER_NUM 15
#endif
#ifndef AMZ_BATTERY_DIVIDER_DEN
#define AMZ_BATTERY_DIVIDER_DEN 1
#endif
#ifndef AMZ_BATTERY_ADC_FULL_SCALE
#define AMZ_BATTERY_ADC_FULL_SCALE 1024
#endif
#ifndef AMZ_BATTERY_MEDIAN_WINDOW
#define AMZ_BATTERY_MEDIAN_WINDOW 7
#endif
// 5 x 10.5 V: a deeply discharged lead-acid string.
#ifndef AMZ_LOW_BATTERY_10MV
#define AMZ_LOW_BATTERY_10MV 5250
#endif
#ifndef AMZ_LOW_BATTERY_HYSTERESIS_10MV
#define AMZ_LOW_BATTERY_HYSTERESIS_10MV 100
#endif

// GPS: no valid GGA for this long -> GPS_STALE, fix quality 0.
#ifndef AMZ_GPS_STALE_MS
#define AMZ_GPS_STALE_MS 2000
#endif
// A wheel-speed reading older than this is not used.
#ifndef AMZ_WHEEL_STALE_MS
#define AMZ_WHEEL_STALE_MS 500
#endif

#endif
