"""Where the CLI keeps the portal's address and the user's token.

``amazing login`` writes them to ``credentials.json`` in the user's configuration directory
(``$XDG_CONFIG_HOME/amazing`` on Linux), readable by the user alone (mode 0600).
``AMAZING_URL`` and ``AMAZING_TOKEN`` take precedence over the file, for scripts and CI.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import platformdirs

from amazing_cli.errors import REFUSED, CliError, bad_input

DEFAULT_URL = "http://127.0.0.1:8000"
CREDENTIALS_FILE = "credentials.json"


def config_dir() -> Path:
    return Path(platformdirs.user_config_dir("amazing", appauthor=False))


def credentials_path() -> Path:
    return config_dir() / CREDENTIALS_FILE


@dataclass(frozen=True)
class Credentials:
    url: str
    token: str | None


def _stored() -> dict[str, str]:
    path = credentials_path()
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as exc:
        raise bad_input(f"cannot read {path}: {exc}; run `amazing login` again") from exc
    return {k: v for k, v in data.items() if isinstance(v, str)} if isinstance(data, dict) else {}


def load(*, url: str | None = None, token: str | None = None) -> Credentials:
    """The address and token to use: options, then the environment, then the stored file."""
    stored = _stored()
    return Credentials(
        url=(url or os.environ.get("AMAZING_URL") or stored.get("url") or DEFAULT_URL).rstrip("/"),
        token=token or os.environ.get("AMAZING_TOKEN") or stored.get("token") or None,
    )


def require_token(credentials: Credentials) -> str:
    if not credentials.token:
        raise CliError("no token: run `amazing login` or set AMAZING_TOKEN", exit_code=REFUSED)
    return credentials.token


def save(*, url: str, token: str) -> Path:
    """Store the address and token, readable by the user alone."""
    path = credentials_path()
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    tmp = path.with_suffix(".tmp")
    # Created 0600 from the start: the token is never readable by others, not even briefly.
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as out:
        json.dump({"url": url, "token": token}, out)
    os.chmod(tmp, 0o600)
    os.replace(tmp, path)
    return path


def forget() -> bool:
    try:
        credentials_path().unlink()
    except FileNotFoundError:
        return False
    return True


def stored_credentials() -> Credentials | None:
    """What ``amazing login`` stored, whatever the options and environment say."""
    stored = _stored()
    if not stored.get("token"):
        return None
    return Credentials(url=(stored.get("url") or DEFAULT_URL).rstrip("/"), token=stored["token"])
