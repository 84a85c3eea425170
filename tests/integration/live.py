"""A live portal (the real ASGI server on the test database) for tests of the public API and
the command-line client, lighter than the whole stack (no worker or beat)."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from django.conf import settings

from bench.stack import Proc, free_port, python, wait_http
from portal.processes import agent_process, web_process
from tests.integration.stack import TEST_WEB


@dataclass
class LivePortal:
    url: str
    procs: list[Proc] = field(default_factory=list)

    def output(self, last: int = 60) -> str:
        return "\n".join(p.output(last) for p in self.procs)


@contextlib.contextmanager
def live_portal(
    tmp_path: Path, *, agent_port: int | None = None, **env_changes: str
) -> Iterator[LivePortal]:
    """The web process on the test database; with ``agent_port``, a base-station agent (the
    simulated robot) there too, sharing the agent token. No worker or beat."""
    db = settings.DATABASES["default"]
    assert db["ENGINE"].endswith("postgresql"), "the live server runs on PostgreSQL"
    port = free_port()
    var_dir = tmp_path / "var"
    var_dir.mkdir(exist_ok=True)
    env = dict(os.environ)
    env.update(
        {
            "DJANGO_DEBUG": "1",
            # The test's key: the server reads what the test wrote under it (MFA secrets are
            # encrypted with a key derived from it, core/crypto.py).
            "DJANGO_SECRET_KEY": settings.SECRET_KEY,
            "DATABASE_URL": f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}",
            "AMAZING_VAR_DIR": str(var_dir),
            "AGENT_TOKEN": secrets.token_urlsafe(24),
            "AGENT_DATA_DIR": str(tmp_path / "agent"),
            "PYTHONUNBUFFERED": "1",
            **TEST_WEB,
            **env_changes,
        }
    )
    specs = [web_process(python=python(), port=port, access_log=False)]
    if agent_port is not None:
        specs.insert(0, agent_process(python=python(), port=agent_port))
    portal = LivePortal(url=f"http://127.0.0.1:{port}")
    try:
        for spec in specs:
            portal.procs.append(Proc(spec.name, list(spec.argv), {**env, **spec.env}))
        if agent_port is not None:
            wait_http(f"http://127.0.0.1:{agent_port}/healthz", 30, portal.procs)
        wait_http(f"{portal.url}/healthz", 30, portal.procs)
        yield portal
    finally:
        for proc in portal.procs:
            proc.tell()
        for proc in portal.procs:
            proc.stop()


@pytest.fixture(scope="module")
def live_web(tmp_path_factory, django_db_setup) -> Iterator[LivePortal]:
    """The portal's web process alone, throttles as configured; one for a module's tests (it
    keeps nothing of its own between requests: what a test wrote is deleted after it, and the
    cache it shares with the test process is emptied before each test)."""
    with live_portal(tmp_path_factory.mktemp("live-web")) as portal:
        yield portal
