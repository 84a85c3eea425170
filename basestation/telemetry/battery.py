"""Battery voltage filtering on the base station.

The thesis (§3.4, figure 3.20) saw reading errors as single very high or very low values.
A mean over a window moves a long way for one such spike; the median of an odd window does
not move at all while the spikes are fewer than half of the window.
"""

from __future__ import annotations

import math
import statistics
from collections import deque

DEFAULT_BATTERY_WINDOW = 9  # under half a second at 20 Hz: a real voltage change shows quickly


class MedianFilter:
    """Running median over the last ``window`` values."""

    def __init__(self, window: int = DEFAULT_BATTERY_WINDOW) -> None:
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"window must be a positive integer, got {window!r}")
        self.window = window
        self._values: deque[float] = deque(maxlen=window)

    def add(self, value: float) -> float:
        """Take one reading and return the filtered value.

        A non-finite reading (NaN, ±inf) is refused instead of being stored: once in the
        window a NaN would make every later median meaningless.
        """
        if not math.isfinite(value):
            raise ValueError(f"reading must be a finite number, got {value!r}")
        self._values.append(float(value))
        return statistics.median(self._values)

    @property
    def value(self) -> float | None:
        """The current median, ``None`` before the first reading."""
        return statistics.median(self._values) if self._values else None

    def clear(self) -> None:
        self._values.clear()

    def __len__(self) -> int:
        return len(self._values)


class BatteryFilter(MedianFilter):
    """The battery voltage median filter (``battery_v`` in, filtered ``battery_v`` out)."""

    @property
    def battery_v(self) -> float | None:
        return self.value
