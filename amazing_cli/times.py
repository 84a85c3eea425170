"""Instants on the command line: RFC 3339, or relative to now (``+90s``, ``+5m``, ``+2h``)."""

from __future__ import annotations

import math
import re
from datetime import UTC, datetime, timedelta

from amazing_cli.errors import bad_input

RELATIVE = re.compile(r"^\+(\d+(?:\.\d+)?)([smhd])$")
UNIT_S = {"s": 1, "m": 60, "h": 3600, "d": 86400}


def now() -> datetime:
    return datetime.now(UTC)


def parse_instant(text: str, *, option: str) -> datetime:
    """An aware instant from ``text``; a time without an offset is in the local time zone."""
    relative = RELATIVE.match(text.strip())
    if relative:
        return now() + timedelta(seconds=float(relative[1]) * UNIT_S[relative[2]])
    try:
        value = datetime.fromisoformat(text.strip())
    except ValueError as exc:
        raise bad_input(
            f"{option} {text!r}: give a time such as 2026-05-01T10:00+01:00, or +30m"
        ) from exc
    return value if value.tzinfo else value.astimezone()


def next_second(value: datetime) -> datetime:
    """``value`` rounded up to a whole second: booked times read well."""
    whole = value.replace(microsecond=0)
    return whole if whole == value else whole + timedelta(seconds=1)


def iso(value: datetime) -> str:
    return value.astimezone(UTC).isoformat().replace("+00:00", "Z")


def parse_api(text: str) -> datetime:
    return datetime.fromisoformat(text.replace("Z", "+00:00"))


def local(text: str | None) -> str:
    """An API instant as local wall-clock time, for people."""
    if not text:
        return "-"
    return parse_api(text).astimezone().strftime("%Y-%m-%d %H:%M:%S")


def seconds(value: float) -> str:
    if value < 120:
        return f"{value:g} s"
    minutes = value / 60
    return f"{minutes:.0f} min" if minutes < 120 else f"{minutes / 60:.1f} h"


def ceil_s(value: float) -> int:
    return math.ceil(value - 1e-9)
