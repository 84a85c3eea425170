"""How to reach the testbed's scheduler, read from ``SCHEDULER_*`` environment variables.

``portal/settings.py`` calls :func:`from_env`; ``None`` means no scheduler is configured
(the fixed nodes are then booked by the portal alone). Every bad value is a ``ValueError``
that names the variable. README.md ("Configuration") and docs/integration.md list them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path
from urllib.parse import urlsplit

DIALECTS = ("omf",)

URL = "SCHEDULER_URL"
DIALECT = "SCHEDULER_DIALECT"
ACCOUNT = "SCHEDULER_ACCOUNT"
# The names of the variables that hold a secret, not secrets.
TOKEN = "SCHEDULER_TOKEN"  # noqa: S105
TOKEN_FILE = "SCHEDULER_TOKEN_FILE"  # noqa: S105
CLIENT_CERT = "SCHEDULER_CLIENT_CERT"
CLIENT_KEY = "SCHEDULER_CLIENT_KEY"
VERIFY_TLS = "SCHEDULER_VERIFY_TLS"
CA_BUNDLE = "SCHEDULER_CA_BUNDLE"
CONNECT_TIMEOUT_S = "SCHEDULER_CONNECT_TIMEOUT_S"
READ_TIMEOUT_S = "SCHEDULER_READ_TIMEOUT_S"
RESOURCES = "SCHEDULER_RESOURCES"
GRANULARITY_S = "SCHEDULER_GRANULARITY_S"

ENV_NAMES = (
    URL,
    DIALECT,
    ACCOUNT,
    TOKEN,
    TOKEN_FILE,
    CLIENT_CERT,
    CLIENT_KEY,
    VERIFY_TLS,
    CA_BUNDLE,
    CONNECT_TIMEOUT_S,
    READ_TIMEOUT_S,
    RESOURCES,
    GRANULARITY_S,
)

DEFAULT_ACCOUNT = "amazing"
DEFAULT_CONNECT_TIMEOUT_S = 3.0
DEFAULT_READ_TIMEOUT_S = 10.0
MAX_TIMEOUT_S = 300.0
MAX_GRANULARITY_S = 86400

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


@dataclass(frozen=True)
class SchedulerConfig:
    """Where the scheduler is, who we are to it, and which of our resources it owns.

    ``owned_resources`` are glob patterns of resource names (``node-*``); empty means every
    fixed node. ``verify_tls`` with ``ca_bundle`` trusts that bundle instead of the system's.
    """

    base_url: str
    dialect: str = "omf"
    account_name: str = DEFAULT_ACCOUNT
    token: str | None = field(default=None, repr=False)
    client_cert: Path | None = None
    client_key: Path | None = None
    verify_tls: bool = True
    ca_bundle: Path | None = None
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S
    read_timeout_s: float = DEFAULT_READ_TIMEOUT_S
    owned_resources: tuple[str, ...] = ()
    granularity_s: int = 1

    def __post_init__(self) -> None:
        _check_url(URL, self.base_url)
        if self.dialect not in DIALECTS:
            raise ValueError(f"{DIALECT}={self.dialect!r}: known dialects are {DIALECTS}")
        if not self.account_name.strip():
            raise ValueError(f"{ACCOUNT} must not be empty")
        if self.token is not None:
            _check_token(TOKEN, self.token)
        if self.client_key is not None and self.client_cert is None:
            raise ValueError(f"{CLIENT_KEY} needs {CLIENT_CERT}")
        if self.client_cert is not None and not self.base_url.startswith("https://"):
            raise ValueError(f"{CLIENT_CERT} needs an https:// {URL}")
        if self.ca_bundle is not None and not self.verify_tls:
            raise ValueError(f"{CA_BUNDLE} is set but {VERIFY_TLS} is off")
        for name, timeout_s in (
            (CONNECT_TIMEOUT_S, self.connect_timeout_s),
            (READ_TIMEOUT_S, self.read_timeout_s),
        ):
            if not (math.isfinite(timeout_s) and 0 < timeout_s <= MAX_TIMEOUT_S):
                raise ValueError(f"{name}={timeout_s} must be above 0 and at most {MAX_TIMEOUT_S}")
        if not 1 <= self.granularity_s <= MAX_GRANULARITY_S:
            raise ValueError(
                f"{GRANULARITY_S}={self.granularity_s} must be between 1 and {MAX_GRANULARITY_S}"
            )

    def owns(self, *, resource_name: str, is_fixed_node: bool) -> bool:
        """Whether the scheduler, not the portal, books this resource."""
        if not self.owned_resources:
            return is_fixed_node
        return any(fnmatchcase(resource_name, pattern) for pattern in self.owned_resources)

    @property
    def timeouts_s(self) -> tuple[float, float]:
        return (self.connect_timeout_s, self.read_timeout_s)


def from_env(environ: Mapping[str, str]) -> SchedulerConfig | None:
    """The scheduler's configuration, or ``None`` when ``SCHEDULER_URL`` is not set."""
    env = {name: environ.get(name, "").strip() for name in ENV_NAMES}
    if not env[URL]:
        stray = [name for name in ENV_NAMES if env[name]]
        if stray:
            raise ValueError(f"{', '.join(stray)} set but {URL} is not")
        return None
    verify_tls = _bool(VERIFY_TLS, env[VERIFY_TLS], default=True)
    return SchedulerConfig(
        base_url=env[URL].rstrip("/"),
        dialect=env[DIALECT] or "omf",
        account_name=env[ACCOUNT] or DEFAULT_ACCOUNT,
        token=_secret(env, TOKEN, TOKEN_FILE),
        client_cert=_readable_file(CLIENT_CERT, env[CLIENT_CERT]),
        client_key=_readable_file(CLIENT_KEY, env[CLIENT_KEY]),
        verify_tls=verify_tls,
        ca_bundle=_readable_file(CA_BUNDLE, env[CA_BUNDLE]),
        connect_timeout_s=_float(
            CONNECT_TIMEOUT_S, env[CONNECT_TIMEOUT_S], DEFAULT_CONNECT_TIMEOUT_S
        ),
        read_timeout_s=_float(READ_TIMEOUT_S, env[READ_TIMEOUT_S], DEFAULT_READ_TIMEOUT_S),
        owned_resources=_patterns(env[RESOURCES]),
        granularity_s=_int(GRANULARITY_S, env[GRANULARITY_S], 1),
    )


def _check_url(name: str, url: str) -> None:
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"{name}={url!r} must be an http:// or https:// URL with a host")
    if parts.query or parts.fragment:
        raise ValueError(f"{name}={url!r} must not have a query or fragment")
    try:
        parts.port  # noqa: B018 - raises ValueError for a port out of range
    except ValueError as exc:
        raise ValueError(f"{name}={url!r}: {exc}") from None


def _check_token(name: str, token: str) -> None:
    # It goes into an HTTP header: no line breaks, no spaces around or inside.
    if not token or any(ch.isspace() for ch in token) or not token.isprintable():
        raise ValueError(f"{name} must be one printable word without spaces")


def _secret(env: Mapping[str, str], name: str, file_name: str) -> str | None:
    value, path = env[name], env[file_name]
    if value and path:
        raise ValueError(f"set only one of {name} and {file_name}")
    if not path:
        return value or None
    try:
        value = Path(path).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{file_name}={path} cannot be read: {exc}") from None
    if not value:
        raise ValueError(f"{file_name}={path} is empty")
    _check_token(file_name, value)
    return value


def _readable_file(name: str, raw: str) -> Path | None:
    if not raw:
        return None
    path = Path(raw)
    try:
        with path.open("rb"):
            pass
    except OSError as exc:
        raise ValueError(f"{name}={raw} cannot be read: {exc}") from None
    if not path.is_file():
        raise ValueError(f"{name}={raw} is not a file")
    return path


def _bool(name: str, raw: str, *, default: bool) -> bool:
    if not raw:
        return default
    lowered = raw.lower()
    if lowered in _TRUE:
        return True
    if lowered in _FALSE:
        return False
    raise ValueError(f"{name}={raw!r} must be one of on/off, true/false, yes/no, 1/0")


def _float(name: str, raw: str, default: float) -> float:
    if not raw:
        return default
    try:
        return float(raw)
    except ValueError:
        raise ValueError(f"{name}={raw!r} is not a number") from None


def _int(name: str, raw: str, default: int) -> int:
    if not raw:
        return default
    try:
        return int(raw)
    except ValueError:
        raise ValueError(f"{name}={raw!r} is not a whole number") from None


def _patterns(raw: str) -> tuple[str, ...]:
    return tuple(pattern.strip() for pattern in raw.split(",") if pattern.strip())
