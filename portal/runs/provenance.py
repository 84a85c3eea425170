"""How a run was made: what the portal records of it at staging and at collection.

A reviewer asks months later which firmware drove the robot, with which limits, on which
rail, whether the base station's clock was in sync, how good the radio link was, and which
software computed the results. The answers come from the run's base-station agent (its
``provenance``, ``basestation/provenance.py``) and from the portal itself, and are kept in one
JSON column of the run (``Run.provenance``), read with the run and never per sample:

- ``staged``: when the run was staged, what the portal sent (``limits``), the portal's
  version, and the agent and its robot's firmware as the agent then described them;
- ``collected``: when the run was closed, what the agent's control loop recorded as the run
  started and ended (the agent and firmware then, the clock at start and end, the link over
  the run), and the portal's version.

Whatever an agent sends is reduced here to the known keys and types (an older agent's
answer simply leaves a part empty), so the page, the API and the downloads read one shape,
``FORMAT_VERSION`` of it.
"""

from __future__ import annotations

import math
from datetime import datetime
from importlib.metadata import PackageNotFoundError, version
from typing import Any, Final

from django.db import transaction

from portal.runs.models import Run

FORMAT_VERSION: Final = 1

try:
    PORTAL_VERSION: Final = version("amazing-mobile-node")
except PackageNotFoundError:  # a source tree that was never installed
    PORTAL_VERSION = "0+unknown"  # type: ignore[misc]

_AGENT_NUMBERS: Final = (
    "control_hz",
    "max_velocity_mps",
    "max_accel_mps2",
    "robot_hard_max_velocity_mps",
    "low_battery_v",
)
_CLOCK_NUMBERS: Final = ("offset_s", "max_error_s", "estimated_error_s")
_LINK_COUNTS: Final = ("exchanges", "answered", "lost")


def _text(value: Any, limit: int = 200) -> str | None:
    return value[:limit] if isinstance(value, str) else None


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _count(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


def _flag(value: Any) -> bool | None:
    return value if isinstance(value, bool) else None


def _mapping(value: Any) -> dict[str, Any] | None:
    return value if isinstance(value, dict) else None


def _rail(raw: Any) -> dict[str, Any] | None:
    rail = _mapping(raw)
    if rail is None:
        return None
    return {
        "name": _text(rail.get("name")),
        "file": _text(rail.get("file"), 500),
        "sha256": _text(rail.get("sha256"), 64),
        "length_m": _number(rail.get("length_m")),
    }


def agent_clean(raw: Any) -> dict[str, Any] | None:
    """The agent's facts (version, interface, control rate, limits, rail) in the portal's shape."""
    agent = _mapping(raw)
    if agent is None:
        return None
    return {
        "version": _text(agent.get("version")),
        "resource": _text(agent.get("resource")),
        "interface": _text(agent.get("interface")),
        **{name: _number(agent.get(name)) for name in _AGENT_NUMBERS},
        "robot_confirmed_limits": _flag(agent.get("robot_confirmed_limits")),
        "rail": _rail(agent.get("rail")),
    }


def firmware_clean(raw: Any) -> dict[str, Any] | None:
    """The robot firmware's identity (build id, compiled-in configuration)."""
    firmware = _mapping(raw)
    if firmware is None or not isinstance(firmware.get("build_id"), str):
        return None
    config = _mapping(firmware.get("config")) or {}
    return {
        "build_id": _text(firmware["build_id"], 16),
        "protocol_version": _count(firmware.get("protocol_version")),
        "config": {str(k)[:64]: v for k, v in config.items() if _count(v) is not None},
    }


def clock_clean(raw: Any) -> dict[str, Any] | None:
    clock = _mapping(raw)
    if clock is None:
        return None
    return {
        "synchronized": _flag(clock.get("synchronized")),
        **{name: _number(clock.get(name)) for name in _CLOCK_NUMBERS},
    }


def _rssi(raw: Any) -> dict[str, float | None] | None:
    rssi = _mapping(raw)
    if rssi is None:
        return None
    return {name: _number(rssi.get(name)) for name in ("min", "mean", "max")}


def link_clean(raw: Any) -> dict[str, Any] | None:
    link = _mapping(raw)
    if link is None:
        return None
    return {
        **{name: _count(link.get(name)) for name in _LINK_COUNTS},
        "loss_pct": _number(link.get("loss_pct")),
        "rssi_dbm": _rssi(link.get("rssi_dbm")),
        "robot_rssi_dbm": _rssi(link.get("robot_rssi_dbm")),
    }


def provenance_at_staging(
    *, agent_run: dict[str, Any], limits: dict[str, Any], now: datetime
) -> dict[str, Any]:
    """What staging records: the limits sent and the agent as its answer described itself."""
    provenance = _mapping(agent_run.get("provenance")) or {}
    return {
        "at": now.isoformat(),
        "portal_version": PORTAL_VERSION,
        "limits": {
            "max_velocity_mps": _number(limits.get("max_velocity_mps")),
            "max_accel_mps2": _number(limits.get("max_accel_mps2")),
        },
        "agent": agent_clean(provenance.get("agent")),
        "firmware": firmware_clean(provenance.get("firmware")),
    }


def provenance_at_collection(*, agent_run: dict[str, Any], now: datetime) -> dict[str, Any]:
    """What collection records once the agent has ended the run: what its control loop wrote
    as the run started and ended. A run that never started there has no ``started``: the
    agent as it is now stands in, marked by ``started_at`` null."""
    provenance = _mapping(agent_run.get("provenance")) or {}
    started = _mapping(provenance.get("started"))
    ended = _mapping(provenance.get("ended")) or {}
    source = started if started is not None else provenance
    return {
        "at": now.isoformat(),
        "portal_version": PORTAL_VERSION,
        "started_at": None if started is None else _text(started.get("at")),
        "ended_at": _text(ended.get("at")),
        "agent": agent_clean(source.get("agent")),
        "firmware": firmware_clean(source.get("firmware")),
        "clock_at_start": None if started is None else clock_clean(started.get("clock")),
        "clock_at_end": clock_clean(ended.get("clock")),
        "link": link_clean(ended.get("link")),
        "cpu_temp_c_at_end": _number(ended.get("cpu_temp_c")),
    }


def run_provenance_record(
    *, run_id: int, part: str, value: dict[str, Any], keep_first: bool = False
) -> None:
    """Keep ``value`` as the run's provenance ``part`` ("staged", "collected").

    ``keep_first``: a part already recorded stays as it is. The record made when the run was
    collected is the agent's final one, the same for every collection; the collector's and a
    sweep's may both close the run, and the second must not rewrite its time."""
    with transaction.atomic():
        run = Run.objects.select_for_update().only("provenance").filter(pk=run_id).first()
        if run is None:
            return
        provenance = dict(run.provenance or {})
        if keep_first and provenance.get(part):
            return
        provenance["format_version"] = FORMAT_VERSION
        provenance[part] = value
        Run.objects.filter(pk=run_id).update(provenance=provenance)


def provenance_view(provenance: Any) -> dict[str, Any]:
    """A run's stored provenance with every part present (None where nothing was recorded)."""
    stored = _mapping(provenance) or {}
    return {
        "format_version": FORMAT_VERSION,
        "staged": _mapping(stored.get("staged")),
        "collected": _mapping(stored.get("collected")),
    }


def provenance_summary(provenance: Any) -> dict[str, Any]:
    """The facts the run page shows first, from whichever record has them (collection's
    over staging's): the run as made, and the firmware or rail changing between the two."""
    view = provenance_view(provenance)
    staged = view["staged"] or {}
    collected = view["collected"] or {}
    agent = collected.get("agent") or staged.get("agent")
    firmware = collected.get("firmware") or staged.get("firmware")
    changed = []
    for part, label in (("firmware", "firmware"), ("agent", "agent")):
        before, after = staged.get(part), collected.get(part)
        if before and after and before != after:
            changed.append(label)
    return {
        "staged": view["staged"],
        "collected": view["collected"],
        "agent": agent,
        "firmware": firmware,
        "limits": staged.get("limits"),
        "changed": changed,
    }
