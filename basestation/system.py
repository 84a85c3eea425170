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
# status bit: ``offset`` is in nanoseconds, not microseconds.
_STA_NANO = 0x2000


class _Timex(ctypes.Structure):
    """The head of struct timex (adjtimex(2)): C types, so the layout follows the platform."""

    _fields_ = [
        ("modes", ctypes.c_uint),
        ("offset", ctypes.c_long),  # µs (ns with STA_NANO): the NTP daemon's last offset
        ("freq", ctypes.c_long),
        ("maxerror", ctypes.c_long),  # µs: the kernel's bound on the clock's error
        ("esterror", ctypes.c_long),  # µs: its estimate of the error
        ("status", ctypes.c_int),
    ]


@dataclass(frozen=True)
class ClockSync:
    """What the kernel says of the clock's discipline: synchronised (None: unknown), the NTP
    offset last applied, and the kernel's maximum and estimated error, in seconds."""

    synchronized: bool | None
    offset_s: float | None = None
    max_error_s: float | None = None
    estimated_error_s: float | None = None

    def to_json_dict(self) -> dict[str, object]:
        return {
            "synchronized": self.synchronized,
            "offset_s": self.offset_s,
            "max_error_s": self.max_error_s,
            "estimated_error_s": self.estimated_error_s,
        }


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
        return self.read().synchronized

    def read(self) -> ClockSync:
        if self._adjtimex is None:
            return ClockSync(synchronized=None)
        buffer = ctypes.create_string_buffer(_TIMEX_BYTES)
        state = self._adjtimex(buffer)
        if state < 0:
            return ClockSync(synchronized=None)
        timex = _Timex.from_buffer(buffer)
        offset_unit_s = 1e-9 if timex.status & _STA_NANO else 1e-6
        return ClockSync(
            synchronized=bool(state != _TIME_ERROR),
            offset_s=timex.offset * offset_unit_s,
            max_error_s=timex.maxerror * 1e-6,
            estimated_error_s=timex.esterror * 1e-6,
        )


_clock = _ClockProbe()


def clock_synchronized() -> bool | None:
    """Whether the kernel clock is NTP-synchronised; None when this cannot be read."""
    return _clock.synchronized()


def clock_sync() -> ClockSync:
    """The clock's sync state and the kernel's offset and error figures (one system call)."""
    return _clock.read()


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
