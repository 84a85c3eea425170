"""The agent's configuration, read once at start from ``AGENT_``-prefixed environment variables.

Every value is parsed and range-checked here so that a mistyped variable stops the agent
with a message naming the variable, instead of surfacing later as a strange robot motion.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

ENV_PREFIX = "AGENT_"
DEFAULT_DATA_DIR = Path("./var/agent")
STORE_FILE_NAME = "runs.sqlite3"
DEFAULT_CPU_TEMP_PATH = Path("/sys/class/thermal/thermal_zone0/temp")
# Five 12 V lead-acid batteries in series: 50 V is 10 V a block, the deep-discharge limit
# that shortens their life; the robot still has enough to brake and reach its dock.
DEFAULT_LOW_BATTERY_V = 50.0
DEFAULT_MIN_FREE_DISK_MB = 200.0
DEFAULT_RETENTION_DAYS = 90.0
# Low among real-time priorities (1-99): above every normal thread, below the kernel's own.
DEFAULT_RT_PRIORITY = 10
# AGENT_CONTROL_CPU unset: the control loop's thread goes on the last CPU the agent may use,
# when it may use two or more (the HTTP server's threads keep the others busier).
AUTO_CPU = -1


# How the agent reaches the robot: "radio" is the RFM69 on the Pi's SPI bus; "sim" the same
# driver on an emulated chip whose robot (the firmware core on simulated physics) lives in
# this process; "sim-flashed" the same with the flashed image itself as the robot's firmware,
# on an emulated ATmega328P (basestation/sim/flashed.py); "sim-udp" the robot in its own
# process (python -m basestation.sim), so it outlives the agent; "simple" a bare kinematic
# model for unit tests.
ROBOT_KINDS = ("radio", "sim", "sim-flashed", "sim-udp", "simple")


class ConfigError(Exception):
    """The environment does not describe a usable agent (the Flask analogue of
    Django's ``ImproperlyConfigured``)."""


@dataclass(frozen=True)
class AgentConfig:
    # The bearer token the portal presents, in the clear (AGENT_TOKEN) ...
    token: str = ""
    # ... and/or the SHA-256 digests (hex) of the tokens accepted (AGENT_TOKEN_SHA256): a
    # base station then holds no usable token, and two digests let a token be rotated
    # without refusing the portal in between.
    token_sha256: tuple[str, ...] = ()
    # The read-only token (AGENT_READ_TOKEN) and/or its digests (AGENT_READ_TOKEN_SHA256), for
    # metrics and status: it reads, and may latch the e-stop, nothing else
    # (basestation.api.auth). Optional.
    read_token: str = field(default="", repr=False)
    read_token_sha256: tuple[str, ...] = ()
    data_dir: Path = DEFAULT_DATA_DIR
    control_hz: float = 20.0
    max_velocity_mps: float = 2.0
    max_accel_mps2: float = 1.0
    rail_length_m: float = 120.0
    resource: str = "mobile-1"
    # Filtered battery voltage under which no run starts and a running one is aborted
    # (0 switches the check off).
    low_battery_v: float = DEFAULT_LOW_BATTERY_V
    # New runs are refused when staging them would leave less than this free on the disk of
    # the run store (0 switches the guard off).
    min_free_disk_mb: float = DEFAULT_MIN_FREE_DISK_MB
    # Ended runs (and their samples) are deleted this long after their end (0 keeps them).
    retention_days: float = DEFAULT_RETENTION_DAYS
    cpu_temp_path: Path = DEFAULT_CPU_TEMP_PATH
    # SCHED_FIFO priority of the control loop's thread (0: normal scheduling).
    rt_priority: int = DEFAULT_RT_PRIORITY
    # CPU the control loop's thread is pinned to: AUTO_CPU picks one, None pins nothing.
    control_cpu: int | None = AUTO_CPU
    robot: str = "sim"
    # sim-udp: the loopback ports of this side's emulated chip and of the robot process.
    sim_base_port: int = 47001
    sim_robot_port: int = 47002
    # radio: the SPI device of the RFM69 and the optional AES key (32 hex digits).
    spi_bus: int = 0
    spi_device: int = 0
    radio_aes_key: str | None = field(default=None, repr=False)
    # The rail's geometry (JSON or TOML, see basestation/telemetry/default_rail.json).
    rail_file: Path | None = None
    # sim: the simulated robot's configuration file (docs/simulator.md; its rail is this
    # agent's), e.g. to give its firmware another build identifier.
    sim_config: Path | None = None

    def __post_init__(self) -> None:
        # Checked here too so that configs built in code (tests, benchmarks) obey the same rules.
        if self.token or not self.token_sha256:
            _check_token(self.token, "token")
        for digest in self.token_sha256 + self.read_token_sha256:
            if not re.fullmatch(r"[0-9a-f]{64}", digest):
                raise ConfigError("token_sha256: each must be a SHA-256 digest (64 hex digits)")
        if self.read_token:
            _check_token(self.read_token, "read_token")
        if set(self.read_token_digests) & set(self.accepted_token_digests):
            # One token in both scopes would be a control token that looks read-only.
            raise ConfigError("the read-only token must differ from the control token")
        _check_range("control_hz", self.control_hz, low=1.0, high=200.0)
        _check_range("max_velocity_mps", self.max_velocity_mps, low=0.01, high=10.0)
        _check_range("max_accel_mps2", self.max_accel_mps2, low=0.01, high=20.0)
        _check_range("rail_length_m", self.rail_length_m, low=1.0, high=100_000.0)
        if not self.resource.strip():
            raise ConfigError("resource must not be empty")
        _check_range("low_battery_v", self.low_battery_v, low=0.0, high=1000.0)
        _check_range("min_free_disk_mb", self.min_free_disk_mb, low=0.0, high=10_000_000.0)
        _check_retention("retention_days", self.retention_days)
        _check_range("rt_priority", self.rt_priority, low=0, high=99)
        if self.control_cpu is not None:
            _check_range("control_cpu", self.control_cpu, low=AUTO_CPU, high=4095)
        if self.robot not in ROBOT_KINDS:
            raise ConfigError(f"robot must be one of {', '.join(ROBOT_KINDS)}, not {self.robot!r}")
        for name in ("sim_base_port", "sim_robot_port"):
            _check_range(name, getattr(self, name), low=1, high=65535)

    @property
    def accepted_token_digests(self) -> tuple[bytes, ...]:
        """The SHA-256 digests of every token this agent accepts."""
        digests = [bytes.fromhex(d) for d in self.token_sha256]
        if self.token:
            digests.append(hashlib.sha256(self.token.encode("utf-8")).digest())
        return tuple(digests)

    @property
    def read_token_digests(self) -> tuple[bytes, ...]:
        """The SHA-256 digests of the read-only tokens (metrics, status; and the e-stop)."""
        digests = [bytes.fromhex(d) for d in self.read_token_sha256]
        if self.read_token:
            digests.append(hashlib.sha256(self.read_token.encode("utf-8")).digest())
        return tuple(digests)

    @property
    def control_period_s(self) -> float:
        return 1.0 / self.control_hz

    @property
    def store_path(self) -> Path:
        return self.data_dir / STORE_FILE_NAME

    def __repr__(self) -> str:
        # Never print the token (logs, tracebacks).
        return (
            f"AgentConfig(token=<hidden>, token_sha256={len(self.token_sha256)} digests, "
            f"read tokens={len(self.read_token_digests)}, "
            f"data_dir={self.data_dir!r}, "
            f"control_hz={self.control_hz}, max_velocity_mps={self.max_velocity_mps}, "
            f"max_accel_mps2={self.max_accel_mps2}, rail_length_m={self.rail_length_m}, "
            f"resource={self.resource!r}, low_battery_v={self.low_battery_v}, "
            f"min_free_disk_mb={self.min_free_disk_mb}, retention_days={self.retention_days}, "
            f"cpu_temp_path={self.cpu_temp_path!r}, rt_priority={self.rt_priority}, "
            f"control_cpu={self.control_cpu}, "
            f"robot={self.robot!r}, rail_file={self.rail_file!r}, "
            f"sim_config={self.sim_config!r})"
        )

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> AgentConfig:
        env = os.environ if environ is None else environ
        low_battery_v = _float_env(env, "LOW_BATTERY_V", DEFAULT_LOW_BATTERY_V, low=0, high=1000)
        min_free_mb = _float_env(env, "MIN_FREE_DISK_MB", DEFAULT_MIN_FREE_DISK_MB, low=0, high=1e7)
        return cls(
            token=_token_from_env(env, required=not _digests_from_env(env)),
            token_sha256=_digests_from_env(env),
            read_token=_secret_from_env(env, "READ_TOKEN") or "",
            read_token_sha256=_digests_from_env(env, "READ_TOKEN_SHA256"),
            data_dir=data_dir_from_env(env),
            control_hz=_float_env(env, "CONTROL_HZ", 20.0, low=1.0, high=200.0),
            max_velocity_mps=_float_env(env, "MAX_VELOCITY_MPS", 2.0, low=0.01, high=10.0),
            max_accel_mps2=_float_env(env, "MAX_ACCEL_MPS2", 1.0, low=0.01, high=20.0),
            rail_length_m=_float_env(env, "RAIL_LENGTH_M", 120.0, low=1.0, high=100_000.0),
            resource=_resource_from_env(env),
            low_battery_v=low_battery_v,
            min_free_disk_mb=min_free_mb,
            retention_days=_retention_from_env(env),
            rt_priority=_rt_priority_from_env(env),
            control_cpu=_control_cpu_from_env(env),
            cpu_temp_path=Path(
                env.get(f"{ENV_PREFIX}CPU_TEMP_PATH", "").strip() or DEFAULT_CPU_TEMP_PATH
            ),
            robot=env.get(f"{ENV_PREFIX}ROBOT", "").strip() or "sim",
            sim_base_port=int(_float_env(env, "SIM_BASE_PORT", 47001, low=1, high=65535)),
            sim_robot_port=int(_float_env(env, "SIM_ROBOT_PORT", 47002, low=1, high=65535)),
            spi_bus=int(_float_env(env, "SPI_BUS", 0, low=0, high=9)),
            spi_device=int(_float_env(env, "SPI_DEVICE", 0, low=0, high=9)),
            radio_aes_key=_secret_from_env(env, "RADIO_AES_KEY"),
            rail_file=Path(env[f"{ENV_PREFIX}RAIL_FILE"])
            if env.get(f"{ENV_PREFIX}RAIL_FILE")
            else None,
            sim_config=_optional_path(env, "SIM_CONFIG"),
        )

    @property
    def retention_s(self) -> float | None:
        return None if self.retention_days == 0 else self.retention_days * 86_400.0


def data_dir_from_env(env: Mapping[str, str] | None = None) -> Path:
    """``AGENT_DATA_DIR``: where the run store lives (also read by the backup command,
    which needs nothing else of the configuration)."""
    env = os.environ if env is None else env
    return Path(env.get(f"{ENV_PREFIX}DATA_DIR", "").strip() or DEFAULT_DATA_DIR)


def _digests_from_env(env: Mapping[str, str], name: str = "TOKEN_SHA256") -> tuple[str, ...]:
    """``AGENT_TOKEN_SHA256`` (or its ``_FILE``): hex SHA-256 digests, comma or space apart."""
    text = _secret_from_env(env, name) or ""
    digests = tuple(d.lower() for d in re.split(r"[\s,]+", text) if d)
    for digest in digests:
        if not re.fullmatch(r"[0-9a-f]{64}", digest):
            raise ConfigError(
                f"{ENV_PREFIX}{name}: {digest[:8]}… is not a SHA-256 digest (64 hex digits)"
            )
    return digests


def _token_from_env(env: Mapping[str, str], *, required: bool = True) -> str:
    token = env.get(f"{ENV_PREFIX}TOKEN")
    token_file = env.get(f"{ENV_PREFIX}TOKEN_FILE")
    if token and token_file:
        raise ConfigError(f"set only one of {ENV_PREFIX}TOKEN and {ENV_PREFIX}TOKEN_FILE, not both")
    if token_file:
        try:
            token = Path(token_file).read_text(encoding="utf-8").strip()
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{ENV_PREFIX}TOKEN_FILE: cannot read {token_file!r}: {exc}") from exc
        _check_token(token, f"{ENV_PREFIX}TOKEN_FILE ({token_file})")
        return token
    if not token:
        if not required:
            return ""
        raise ConfigError(
            f"{ENV_PREFIX}TOKEN, {ENV_PREFIX}TOKEN_FILE or {ENV_PREFIX}TOKEN_SHA256 must be "
            "set: the agent refuses to serve its API without a bearer token"
        )
    _check_token(token, f"{ENV_PREFIX}TOKEN")
    return token


def _optional_path(env: Mapping[str, str], name: str) -> Path | None:
    value = env.get(f"{ENV_PREFIX}{name}", "").strip()
    return Path(value) if value else None


def _secret_from_env(env: Mapping[str, str], name: str) -> str | None:
    """``AGENT_<name>``, or the content of the file named by ``AGENT_<name>_FILE``."""
    value = env.get(f"{ENV_PREFIX}{name}", "").strip()
    path = env.get(f"{ENV_PREFIX}{name}_FILE", "").strip()
    if value and path:
        raise ConfigError(f"set only one of {ENV_PREFIX}{name} and {ENV_PREFIX}{name}_FILE")
    if path:
        try:
            return Path(path).read_text(encoding="utf-8").strip() or None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{ENV_PREFIX}{name}_FILE: cannot read {path!r}: {exc}") from exc
    return value or None


def _check_token(token: str, name: str) -> None:
    if not token:
        raise ConfigError(f"{name} is empty")
    # The token travels in an HTTP header: only visible ASCII survives every proxy unchanged.
    if not all("!" <= ch <= "~" for ch in token):
        raise ConfigError(f"{name} must be printable ASCII without spaces")


def _float_env(
    env: Mapping[str, str], name: str, default: float, *, low: float, high: float
) -> float:
    raw = env.get(f"{ENV_PREFIX}{name}", "").strip()
    if not raw:
        return default
    try:
        value = float(raw)
    except ValueError:
        raise ConfigError(f"{ENV_PREFIX}{name}={raw!r} is not a number") from None
    _check_range(f"{ENV_PREFIX}{name}", value, low=low, high=high)
    return value


def _check_range(name: str, value: float, *, low: float, high: float) -> None:
    if not math.isfinite(value) or not low <= value <= high:
        raise ConfigError(f"{name}={value!r} is out of range [{low}, {high}]")


def _resource_from_env(env: Mapping[str, str]) -> str:
    raw = env.get(f"{ENV_PREFIX}RESOURCE")
    if raw is None:
        return "mobile-1"
    if not raw.strip():
        raise ConfigError(f"{ENV_PREFIX}RESOURCE must not be empty")
    return raw.strip()


def _check_retention(name: str, value: float) -> None:
    # Under a day would delete runs the portal may not have collected yet (it collects
    # within minutes, but an outage of the portal can last a night).
    if not math.isfinite(value) or not (value == 0 or 1.0 <= value <= 36_500.0):
        raise ConfigError(f"{name}={value!r} must be 0 (keep every run) or 1 to 36500 days")


def _retention_from_env(env: Mapping[str, str]) -> float:
    name = f"{ENV_PREFIX}RETENTION_DAYS"
    raw = env.get(name, "").strip()
    if not raw:
        return DEFAULT_RETENTION_DAYS
    try:
        value = float(raw)
    except ValueError:
        raise ConfigError(f"{name}={raw!r} is not a number") from None
    _check_retention(name, value)
    return value


def _rt_priority_from_env(env: Mapping[str, str]) -> int:
    name = f"{ENV_PREFIX}RT_PRIORITY"
    raw = env.get(name, "").strip()
    if not raw:
        return DEFAULT_RT_PRIORITY
    if not raw.isdigit() or not 0 <= int(raw) <= 99:
        raise ConfigError(f"{name}={raw!r} must be an integer from 0 (off) to 99")
    return int(raw)


def _control_cpu_from_env(env: Mapping[str, str]) -> int | None:
    name = f"{ENV_PREFIX}CONTROL_CPU"
    raw = env.get(name, "").strip().lower()
    if not raw:
        return AUTO_CPU
    if raw == "none":
        return None
    if not raw.isdigit() or int(raw) > 4095:
        raise ConfigError(f"{name}={raw!r} must be a CPU number (0, 1, ...) or 'none'")
    return int(raw)
