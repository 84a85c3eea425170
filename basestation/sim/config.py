"""The simulator's configuration: rail, body, battery, GPS, radio and firmware overrides.

A JSON or TOML file, every table optional (defaults are the thesis's robot on the default
rail)::

    seed = 1
    start_track_m = 0.0
    rail_file = "rail.json"  # the agent's rail file (AGENT_RAIL_FILE), relative to this file
    [rail]      # or the rail inline, in the same format: name, centre, points, origin, ...
    [physics]   # PhysicsConfig fields: mass_kg, rolling_resistance, ...
    [battery]   # BatteryConfig fields
    [gps]       # fix = "rtk_fixed" | "rtk_float" | "dgps" | "gps" | "none", rate_hz, ...
    [radio]     # node, base_node, network_id, aes_key_hex, high_power, processing_delay_s
    [firmware]  # amz_robot_config fields: max_velocity_mm_s = 3000, build_id = "bench-1", ...

The rail is the agent's :class:`~basestation.telemetry.rail.Rail` in the agent's format,
given either inline as ``[rail]`` or as ``rail_file``, the path of the same rail file that
``AGENT_RAIL_FILE`` names, so that one file configures both (not both at once; neither: the
agent's default rail). The simulated robot then drives, and its GPS reports, exactly the rail
the agent projects its fixes onto.

Every value is type- and range-checked on load; an error names the file, table and key.
"""

from __future__ import annotations

import ctypes
import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

from basestation.sim.firmware import AmzRobotConfig
from basestation.sim.gps import DEFAULT_FIX_MODELS, FixModel
from basestation.sim.physics import BatteryConfig, PhysicsConfig
from basestation.telemetry.rail import Rail, RailConfigError


class SimConfigError(ValueError):
    """The simulator configuration is unusable; the message names the key."""


@dataclass(frozen=True)
class GpsConfig:
    fix: str = "rtk_fixed"
    rate_hz: float = 10.0
    latency_s: float = 0.05  # epoch to the sentence's last byte on the UART
    utc_start_s: float = 43_200.0  # time of day at simulation time 0 (noon)
    altitude_m: float = 30.0
    sigma_m: float | None = None  # overrides the fix state's noise
    correlation_s: float | None = None

    def model(self) -> FixModel:
        base = DEFAULT_FIX_MODELS[self.fix]
        return replace(
            base,
            sigma_m=base.sigma_m if self.sigma_m is None else self.sigma_m,
            correlation_s=base.correlation_s if self.correlation_s is None else self.correlation_s,
        )


@dataclass(frozen=True)
class RadioConfig:
    """The robot's RFM69 as docs/protocol.md §1 configures it."""

    node: int = 2
    base_node: int = 1
    network_id: int = 100
    aes_key_hex: str | None = None
    high_power: bool = True  # RFM69HW: +17 dBm; RFM69W: +13 dBm
    processing_delay_s: float = 0.002  # frame read -> step -> reply written and TX started

    @property
    def aes_key(self) -> bytes | None:
        return None if self.aes_key_hex is None else bytes.fromhex(self.aes_key_hex)

    def __repr__(self) -> str:  # never print a key
        key = "<hidden>" if self.aes_key_hex else None
        return (
            f"RadioConfig(node={self.node}, base_node={self.base_node}, "
            f"network_id={self.network_id}, aes_key_hex={key}, high_power={self.high_power}, "
            f"processing_delay_s={self.processing_delay_s})"
        )


@dataclass(frozen=True)
class SimConfig:
    rail: Rail = field(default_factory=Rail.default)
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    battery: BatteryConfig = field(default_factory=BatteryConfig)
    gps: GpsConfig = field(default_factory=GpsConfig)
    radio: RadioConfig = field(default_factory=RadioConfig)
    # amz_robot_config overrides: numbers, and ``build_id`` (text, as the firmware reports it)
    firmware: Mapping[str, int | str] = field(default_factory=dict)
    seed: int = 0
    start_track_m: float = 0.0
    wheel_um_per_pulse: int = 0  # 0: no wheel sensor (the default build)
    e_stop_latched_at_boot: bool = False  # the latch as restored from EEPROM
    # The firmware: the portable core built for the host (False), or the flashed image itself
    # on an emulated ATmega328P (True: basestation/sim/flashed.py; no [firmware] overrides).
    flashed: bool = False

    def __post_init__(self) -> None:
        if self.flashed and self.firmware:
            raise SimConfigError(
                "[firmware] overrides the host-built core's configuration; the flashed "
                "image's is compiled in (drop one of them)"
            )

    @classmethod
    def from_mapping(
        cls, data: Mapping[str, Any], *, where: str = "config", base_dir: Path | None = None
    ) -> SimConfig:
        """``base_dir``: where a relative ``rail_file`` lies (the configuration file's
        directory; default the working directory)."""
        if not isinstance(data, Mapping):
            raise SimConfigError(f"{where}: the top level must be a table")
        tables = {"rail", "rail_file", "physics", "battery", "gps", "radio", "firmware"}
        values = {k: v for k, v in data.items() if k not in tables}
        top = _parse(_TOP, values, where)
        kwargs: dict[str, Any] = dict(top)
        if "rail" in data and "rail_file" in data:
            raise SimConfigError(
                f"{where}: rail_file and [rail] both give the rail; keep one of them"
            )
        if "rail" in data:
            kwargs["rail"] = _parse_rail(data["rail"], where)
        if "rail_file" in data:
            kwargs["rail"] = _load_rail_file(data["rail_file"], where, base_dir)
        if "physics" in data:
            kwargs["physics"] = PhysicsConfig(
                **_parse(_PHYSICS, data["physics"], f"{where}: physics")
            )
        if "battery" in data:
            battery = BatteryConfig(**_parse(_BATTERY, data["battery"], f"{where}: battery"))
            if battery.full_v <= battery.empty_v:
                raise SimConfigError(f"{where}: battery.full_v must be above battery.empty_v")
            kwargs["battery"] = battery
        if "gps" in data:
            kwargs["gps"] = GpsConfig(**_parse(_GPS, data["gps"], f"{where}: gps"))
        if "radio" in data:
            kwargs["radio"] = RadioConfig(**_parse(_RADIO, data["radio"], f"{where}: radio"))
        if "firmware" in data:
            kwargs["firmware"] = _parse_firmware(data["firmware"], f"{where}: firmware")
        try:
            return cls(**kwargs)
        except SimConfigError as exc:
            raise SimConfigError(f"{where}: {exc}") from exc

    @classmethod
    def load(cls, path: Path | str) -> SimConfig:
        data = _load_file(Path(path))
        return cls.from_mapping(data, where=str(path), base_dir=Path(path).parent)

    def robot_config(self, base: AmzRobotConfig) -> AmzRobotConfig:
        """The firmware's configuration: its compiled defaults, the radio addresses, then the
        ``[firmware]`` overrides."""
        config = AmzRobotConfig()
        for spec in AmzRobotConfig._fields_:
            setattr(config, spec[0], getattr(base, spec[0]))
        config.node = self.radio.node
        config.base_node = self.radio.base_node
        for name, value in self.firmware.items():
            setattr(config, name, value.encode("ascii") if isinstance(value, str) else value)
        return config


# --- parsing ------------------------------------------------------------------------------------


def _load_file(file: Path) -> dict[str, Any]:
    """A ``.json`` or ``.toml`` file as a dict; errors name the file."""
    suffix = file.suffix.lower()
    if suffix not in (".json", ".toml"):
        raise SimConfigError(f"{file}: use a .json or .toml file")
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as error:
        raise SimConfigError(f"{file}: cannot read: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise SimConfigError(f"{file}: not UTF-8 text") from None
    try:
        data: Any = tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise SimConfigError(f"{file}: not valid TOML: {error}") from None
    except (json.JSONDecodeError, RecursionError) as error:  # RecursionError: nested too deep
        raise SimConfigError(f"{file}: not valid {suffix[1:].upper()}: {error}") from None
    if not isinstance(data, dict):
        raise SimConfigError(f"{file}: the top level must be a table/object")
    return data


def _parse_rail(data: Any, where: str) -> Rail:
    """An inline ``[rail]`` table: the agent's rail format, checked by the agent's rules."""
    try:
        return Rail.from_mapping(data)
    except RailConfigError as error:
        # The rail's own field names (points[2].lat), under the table that holds them.
        key = "rail" if error.field == "rail" else f"rail.{error.field}"
        raise SimConfigError(f"{where}: {key}: {error.message}") from None


def _load_rail_file(value: Any, where: str, base_dir: Path | None) -> Rail:
    if not isinstance(value, str) or not value.strip():
        raise SimConfigError(
            f"{where}: rail_file must be the path of a rail file (.json or .toml), got {value!r}"
        )
    path = Path(value)
    if base_dir is not None and not path.is_absolute():
        # Relative to the configuration file, so the pair can move together.
        path = base_dir / path
    try:
        return Rail.from_file(path)
    except RailConfigError as error:
        raise SimConfigError(f"{where}: rail_file: {error}") from None


# name: (kind, low, high); kinds: float, int, bool, str, and "?" for optional (None allowed).
_Spec = dict[str, tuple[str, float, float]]

_TOP: Final[_Spec] = {
    "seed": ("int", 0, 2**63 - 1),
    "start_track_m": ("float", -1e6, 1e6),
    "wheel_um_per_pulse": ("int", 0, 1_000_000),
    "e_stop_latched_at_boot": ("bool", 0, 1),
    "flashed": ("bool", 0, 1),
}
_PHYSICS: Final[_Spec] = {
    "mass_kg": ("float", 1.0, 1000.0),
    "rolling_resistance": ("float", 0.0, 0.5),
    "motor_full_scale_mps": ("float", 0.1, 50.0),
    "throttle_time_constant_s": ("float", 0.001, 5.0),
    "speed_loop_bandwidth_rad_s": ("float", 0.1, 200.0),
    "speed_loop_damping": ("float", 0.1, 5.0),
    "max_drive_force_n": ("float", 1.0, 1e5),
    "max_brake_force_n": ("float", 1.0, 1e5),
    "throttle_deadband_mps": ("float", 0.0, 1.0),
    "short_brake_n_per_mps": ("float", 0.1, 1e5),
    "motor_force_per_amp_n": ("float", 0.01, 1e4),
    "motor_winding_ohm": ("float", 0.0, 100.0),
    "wheel_slip": ("float", 0.0, 0.9),
}
_BATTERY: Final[_Spec] = {
    "batteries": ("int", 1, 20),
    "capacity_ah": ("float", 0.1, 1000.0),
    "initial_soc": ("float", 0.0, 1.0),
    "empty_v": ("float", 1.0, 30.0),
    "full_v": ("float", 1.0, 30.0),
    "internal_resistance_ohm": ("float", 0.0, 10.0),
    "idle_current_a": ("float", 0.0, 100.0),
    "adc_noise_counts": ("float", 0.0, 100.0),
    "adc_spike_probability": ("float", 0.0, 1.0),
    "adc_spike_v": ("float", 0.0, 100.0),
}
_GPS: Final[_Spec] = {
    "fix": ("str", 0, 0),
    "rate_hz": ("float", 0.1, 50.0),
    "latency_s": ("float", 0.0, 1.0),
    "utc_start_s": ("float", 0.0, 86_399.0),
    "altitude_m": ("float", -500.0, 9000.0),
    "sigma_m": ("float?", 0.0, 1000.0),
    "correlation_s": ("float?", 0.0, 3600.0),
}
_RADIO: Final[_Spec] = {
    "node": ("int", 0, 255),
    "base_node": ("int", 0, 255),
    "network_id": ("int", 0, 255),
    "aes_key_hex": ("str?", 0, 0),
    "high_power": ("bool", 0, 1),
    "processing_delay_s": ("float", 0.0, 0.1),
}


def _parse(spec: _Spec, data: Any, where: str) -> dict[str, Any]:
    if not isinstance(data, Mapping):
        raise SimConfigError(f"{where} must be a table")
    unknown = sorted(set(data) - set(spec))
    if unknown:
        raise SimConfigError(
            f"{where}: unknown key(s) {', '.join(map(str, unknown))}"
            f" (known: {', '.join(sorted(spec))})"
        )
    out: dict[str, Any] = {}
    for name, value in data.items():
        kind, low, high = spec[name]
        key = f"{where}.{name}"
        if kind.endswith("?"):
            if value is None:
                out[name] = None
                continue
            kind = kind[:-1]
        if kind == "bool":
            if not isinstance(value, bool):
                raise SimConfigError(f"{key} must be true or false, got {value!r}")
            out[name] = value
        elif kind == "str":
            if not isinstance(value, str):
                raise SimConfigError(f"{key} must be a string, got {value!r}")
            out[name] = value
        elif kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise SimConfigError(f"{key} must be an integer, got {value!r}")
            if not low <= value <= high:
                raise SimConfigError(f"{key} = {value} not in {low:g}..{high:g}")
            out[name] = value
        else:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise SimConfigError(f"{key} must be a number, got {value!r}")
            number = float(value)
            if not math.isfinite(number) or not low <= number <= high:
                raise SimConfigError(f"{key} = {value} not in {low:g}..{high:g}")
            out[name] = number
    if "fix" in out and out["fix"] not in DEFAULT_FIX_MODELS:
        raise SimConfigError(
            f"{where}.fix = {out['fix']!r} is not one of {', '.join(DEFAULT_FIX_MODELS)}"
        )
    key_hex = out.get("aes_key_hex")
    if key_hex is not None:
        try:
            key_bytes = bytes.fromhex(key_hex)
        except ValueError:
            key_bytes = b""
        if len(key_bytes) != 16:
            raise SimConfigError(f"{where}.aes_key_hex must be 32 hex digits (a 16-byte key)")
    return out


# The longest build identifier the identity frame carries (docs/protocol.md §2.6).
BUILD_ID_MAX_CHARS: Final = 16


def _parse_firmware(data: Any, where: str) -> dict[str, int | str]:
    if not isinstance(data, Mapping):
        raise SimConfigError(f"{where} must be a table")
    sizes = {spec[0]: spec[1] for spec in AmzRobotConfig._fields_}
    out: dict[str, int | str] = {}
    for name, value in data.items():
        if name not in sizes:
            raise SimConfigError(
                f"{where}: unknown key {name!r} (known: {', '.join(sorted(sizes))})"
            )
        if name in ("node", "base_node"):
            raise SimConfigError(f"{where}.{name}: set radio.{name} instead")
        if name == "build_id":
            if (
                not isinstance(value, str)
                or len(value) > BUILD_ID_MAX_CHARS
                or not all(" " <= c <= "~" for c in value)
            ):
                raise SimConfigError(
                    f"{where}.build_id must be printable ASCII of at most "
                    f"{BUILD_ID_MAX_CHARS} characters, got {value!r}"
                )
            out[name] = value
            continue
        if isinstance(value, bool) or not isinstance(value, int):
            raise SimConfigError(f"{where}.{name} must be an integer, got {value!r}")
        high = 2 ** (8 * _sizeof(sizes[name])) - 1
        low = 1 if name in _POSITIVE_FIRMWARE else 0
        if not low <= value <= high:
            raise SimConfigError(f"{where}.{name} = {value} not in {low}..{high}")
        out[name] = value
    return out


_POSITIVE_FIRMWARE: Final = frozenset(
    {
        "accel_mm_s2",
        "stop_decel_mm_s2",
        "dead_man_ms",
        "full_scale_mm_s",
        "duty_max",
        "accel_min_mm_s2",
        "accel_max_mm_s2",
        "battery_vref_mv",
        "battery_divider_num",
        "battery_divider_den",
        "battery_adc_full_scale",
        "battery_median_window",
    }
)


def _sizeof(ctype: Any) -> int:
    return int(ctypes.sizeof(ctype))
