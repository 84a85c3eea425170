"""Facts about the base station itself for ``/status``: CPU temperature, clock sync, disk.

Each probe answers ``None`` when the fact is not available on this machine (no thermal
zone in a container, no adjtimex outside Linux) instead of failing: ``/status`` must work
everywhere the agent runs. All are cheap enough to run on every request (a sysfs read, one
system call, one ``statvfs``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

logger = logging.getLogger(__name__)

# adjtimex(2) returns TIME_ERROR when the kernel clock is not synchronised (STA_UNSYNC): the
# flag NTP daemons (systemd-timesyncd, chrony, ntpd) clear once they discipline the clock.
# It is exactly what `timedatectl show -p NTPSynchronized` reports, without a subprocess or
# D-Bus, so it is cheap enough for every /status call.
_TIME_ERROR = 5
# struct timex is about 200 bytes on 64-bit Linux; a zeroed larger buffer with modes = 0
# (read only, needs no privilege) is valid on every architecture.
_TIMEX_BYTES = 512


def cpu_temp_c(path: Path) -> float | None:
    """The SoC temperature in °C from a thermal-zone file (millidegrees), or None."""
    try:
        raw = path.read_text(encoding="ascii").strip()
        return int(raw) / 1000.0
    except (OSError, ValueError, UnicodeDecodeError):
        return None


class _ClockProbe:
    def __init__(self) -> None:
        self._adjtimex = None
        try:
            name = ctypes.util.find_library("c")
            libc = ctypes.CDLL(name, use_errno=True) if name else None
            self._adjtimex = getattr(libc, "adjtimex", None)
        except OSError:
            logger.debug("no libc adjtimex: clock sync state unknown")

    def synchronized(self) -> bool | None:
        if self._adjtimex is None:
            return None
        buffer = ctypes.create_string_buffer(_TIMEX_BYTES)
        state = self._adjtimex(buffer)
        if state < 0:
            return None
        return bool(state != _TIME_ERROR)


_clock = _ClockProbe()


def clock_synchronized() -> bool | None:
    """Whether the kernel clock is NTP-synchronised; None when this cannot be read."""
    return _clock.synchronized()


@dataclass(frozen=True)
class DiskSpace:
    free_bytes: int
    total_bytes: int


def disk_space(path: Path) -> DiskSpace | None:
    """Space on the file system holding ``path`` (what an unprivileged writer may use)."""
    try:
        usage = shutil.disk_usage(path)
    except OSError:
        return None
    return DiskSpace(free_bytes=usage.free, total_bytes=usage.total)
