"""The stand-in broker's switches: the flags, the ``SCHEDULER_STANDIN_*`` variables they
override, and the :class:`StandinConfig` both make (docs/integration.md lists them)."""

from __future__ import annotations

import argparse
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

ENV_PREFIX = "SCHEDULER_STANDIN_"
CONFLICT_MODES = ("401", "409", "zombie")
DEFAULT_NODES = tuple(f"node-{i:02d}" for i in range(1, 25))
_NODE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,62}$")


class ConfigError(ValueError):
    """A switch has a value the stand-in cannot run with."""


@dataclass(frozen=True)
class StandinConfig:
    conflict_as: str = "401"
    granularity_s: int = 1
    empty_as_404: bool = False
    token: str | None = field(default=None, repr=False)
    nodes: tuple[str, ...] = DEFAULT_NODES
    db_path: str = ":memory:"
    test_control: bool = False
    domain: str = "amazing"

    def __post_init__(self) -> None:
        if self.conflict_as not in CONFLICT_MODES:
            raise ConfigError(f"conflict-as must be one of {', '.join(CONFLICT_MODES)}")
        if not 1 <= self.granularity_s <= 86400:
            raise ConfigError("granularity-s must be between 1 and 86400")
        if self.token is not None and (
            not self.token or any(ch.isspace() for ch in self.token) or not self.token.isprintable()
        ):
            raise ConfigError("the token must be one printable word without spaces")
        if not self.nodes:
            raise ConfigError("the stand-in needs at least one node")
        bad = [name for name in self.nodes if not _NODE_NAME.match(name)]
        if bad:
            raise ConfigError(f"node names must be letters, digits, '.', '_' or '-': {bad}")
        if len(set(self.nodes)) != len(self.nodes):
            raise ConfigError("node names must be unique")
        if not self.db_path:
            raise ConfigError("db must be a file path or :memory:")

    @property
    def conflict_code(self) -> int:
        return 409 if self.conflict_as == "409" else 401

    @classmethod
    def from_env(cls, environ: Mapping[str, str]) -> StandinConfig:
        def get(name: str) -> str:
            return environ.get(f"{ENV_PREFIX}{name}", "").strip()

        values: dict[str, Any] = {}
        if get("CONFLICT_AS"):
            values["conflict_as"] = get("CONFLICT_AS")
        if get("GRANULARITY_S"):
            values["granularity_s"] = _int_option("GRANULARITY_S", get("GRANULARITY_S"))
        if get("EMPTY_AS_404"):
            values["empty_as_404"] = _bool_option("EMPTY_AS_404", get("EMPTY_AS_404"))
        if get("TEST_CONTROL"):
            values["test_control"] = _bool_option("TEST_CONTROL", get("TEST_CONTROL"))
        if get("NODES"):
            values["nodes"] = _node_list(get("NODES"))
        if get("DB"):
            values["db_path"] = get("DB")
        token = _token(get("TOKEN"), get("TOKEN_FILE"), label=f"{ENV_PREFIX}TOKEN")
        if token is not None:
            values["token"] = token
        return cls(**values)


def _int_option(name: str, raw: str) -> int:
    try:
        return int(raw)
    except ValueError:
        raise ConfigError(f"{name}={raw!r} is not a whole number") from None


def _bool_option(name: str, raw: str) -> bool:
    lowered = raw.lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise ConfigError(f"{name}={raw!r} must be on or off")


def _node_list(raw: str) -> tuple[str, ...]:
    return tuple(name.strip() for name in raw.split(",") if name.strip())


def _token(value: str, path: str, *, label: str) -> str | None:
    if value and path:
        raise ConfigError(f"set only one of {label} and {label}_FILE")
    if not path:
        return value or None
    try:
        return Path(path).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{label}_FILE={path} cannot be read: {exc}") from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m bookings.scheduler.standin",
        description="Stand-in omf_sfa broker (leases of the fixed nodes). Flags override "
        f"the {ENV_PREFIX}* variables.",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on")
    parser.add_argument("--port", type=int, default=8710, help="TCP port (0: a free one)")
    parser.add_argument("--threads", type=int, default=8, help="HTTP worker threads")
    parser.add_argument("--log-level", default="INFO")
    parser.add_argument("--conflict-as", choices=CONFLICT_MODES, help="how a clash is answered")
    parser.add_argument("--granularity-s", type=int, help="lease times on multiples of this")
    parser.add_argument(
        "--empty-as-404",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="answer an empty listing as 404",
    )
    parser.add_argument("--token", help="require this bearer token")
    parser.add_argument("--token-file", help="require the bearer token in this file")
    parser.add_argument("--nodes", help="comma-separated node names (default node-01..node-24)")
    parser.add_argument("--db", help="SQLite file that keeps leases across restarts")
    parser.add_argument(
        "--test-control",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="serve /_standin/ endpoints: clock, faults, reset (tests only)",
    )
    return parser


def config_from(args: argparse.Namespace, environ: Mapping[str, str]) -> StandinConfig:
    config = StandinConfig.from_env(environ)
    changes: dict[str, Any] = {}
    if args.conflict_as is not None:
        changes["conflict_as"] = args.conflict_as
    if args.granularity_s is not None:
        changes["granularity_s"] = args.granularity_s
    if args.empty_as_404 is not None:
        changes["empty_as_404"] = args.empty_as_404
    if args.test_control is not None:
        changes["test_control"] = args.test_control
    if args.nodes is not None:
        changes["nodes"] = _node_list(args.nodes)
    if args.db is not None:
        changes["db_path"] = args.db
    if args.token is not None or args.token_file is not None:
        changes["token"] = _token(args.token or "", args.token_file or "", label="--token")
    return replace(config, **changes)
