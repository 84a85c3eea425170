"""The system's processes as pytest fixtures: agent(s), ASGI web server, Celery workers, beat.

``stack`` is one fresh system per test on the test database and Redis. ``fault_stack`` is one
per module, for tests that break its parts on purpose: it runs on a Redis server of its own
(a test may stop it; the machine's shared one is never touched), with a second robot, and
every process can be killed and started again (``Stack.kill``, ``Stack.start``).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import redis
from django.conf import settings

from basestation.client import AgentClient
from portal.processes import ProcessSpec, system_processes
from tests.integration.processes import Proc, free_port, python, wait_http

REDIS_SERVER = "/usr/bin/redis-server"
# Prometheus's bearer token for the stack's /metrics.
METRICS_TOKEN = "stack-metrics-token-0123456789"


class RedisServer:
    """A private redis-server on a free port, without persistence: stopping it loses its
    data, as a crashed cache/broker without an append-only file would."""

    def __init__(self, directory: Path) -> None:
        assert shutil.which(REDIS_SERVER), "redis-server is installed with the test services"
        self.directory = directory
        self.directory.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.proc: Proc | None = None

    def url(self, db: int) -> str:
        return f"redis://127.0.0.1:{self.port}/{db}"

    def start(self) -> None:
        argv = [REDIS_SERVER, "--port", str(self.port), "--bind", "127.0.0.1"]
        argv += ["--save", "", "--appendonly", "no", "--dir", str(self.directory)]
        self.proc = Proc("redis", argv, dict(os.environ))
        client = redis.Redis(port=self.port, socket_connect_timeout=0.5)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            with contextlib.suppress(redis.RedisError):
                if client.ping():
                    return
            time.sleep(0.1)
        raise AssertionError(f"redis-server did not start\n{self.proc.output()}")

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.stop()
            self.proc = None


class Stack:
    """The running system: addresses, agent clients, and its processes by name."""

    def __init__(self, specs: list[ProcessSpec], env: dict[str, str]) -> None:
        self.specs = {spec.name: spec for spec in specs}
        self.env = env
        self.procs: dict[str, Proc] = {}
        self.web = ""
        self.streams = ""
        self.agent_url = ""
        self.token = ""
        self.agent: AgentClient | None = None
        self.agent2_url = ""
        self.token2 = ""
        self.agent2: AgentClient | None = None
        self.redis: RedisServer | None = None
        # The stand-in scheduler, when the stack has one.
        self.standin = ""

    # The original fixture handed out a dict; its tests keep reading it that way.
    def __getitem__(self, key: str) -> Any:
        if key == "procs":
            return list(self.procs.values())
        return getattr(self, key)

    def start(self, name: str) -> Proc:
        """Start (or start again) the process ``name`` with its command and environment."""
        spec = self.specs[name]
        self.procs[name] = Proc(name, list(spec.argv), {**self.env, **spec.env})
        return self.procs[name]

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Stop ``name`` and its children: SIGKILL by default (no chance to clean up)."""
        self.procs[name].stop(sig)

    def wait_ready(self, name: str, timeout_s: float = 30) -> None:
        running = list(self.procs.values())
        if name.startswith("agent"):
            url = self.agent_url if name == "agent" else self.agent2_url
            wait_http(f"{url}/healthz", timeout_s, running)
        elif name == "web":
            wait_http(f"{self.web}/accounts/login/", timeout_s, running)
        elif name == "streams":
            wait_http(f"{self.streams}/healthz", timeout_s, running)
        elif name == "broker":
            wait_http(f"{self.standin}/resources/nodes", timeout_s, running)
        elif name in ("worker", "mail"):
            self.procs[name].wait_for_line(lambda line: "ready." in line, timeout_s)
        elif name == "collector":
            self.procs[name].wait_for_line(lambda line: "collector ready" in line, timeout_s)

    def output(self, last: int = 80) -> str:
        return "\n".join(p.output(last) for p in self.procs.values())

    def stop(self) -> None:
        for proc in reversed(list(self.procs.values())):
            proc.stop()


@contextlib.contextmanager
def running_stack(
    var_dir: Path,
    *,
    broker_url: str,
    redis_url: str | None = None,
    second_robot: bool = False,
    with_scheduler: bool = False,
    extra_env: dict[str, str] | None = None,
) -> Iterator[Stack]:
    """Every process of ``system_processes`` on the test database, started and ready."""
    db = settings.DATABASES["default"]
    assert db["ENGINE"].endswith("postgresql"), "the integration test runs on PostgreSQL"
    assert broker_url.startswith("redis://"), "the integration test runs on Redis"
    redis.Redis.from_url(broker_url).flushdb()

    token = secrets.token_urlsafe(24)
    agent_port, web_port, streams_port = free_port(), free_port(), free_port()
    second_port = free_port() if second_robot else None
    var_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.update(
        {
            "DJANGO_DEBUG": "1",
            "DATABASE_URL": f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}",
            "CELERY_BROKER_URL": broker_url,
            "AGENT_TOKEN": token,
            "METRICS_TOKEN": METRICS_TOKEN,
            "AGENT_DATA_DIR": str(var_dir / "agent"),
            "AMAZING_VAR_DIR": str(var_dir),
            "RUN_SWEEP_INTERVAL_S": "0.5",
            "PYTHONUNBUFFERED": "1",
            "LIVE_STREAM_PORT": str(streams_port),
            # Two small web processes: the tests' stack shares two cores with the rest.
            "WEB_WORKERS": "2",
            "WEB_THREADS": "4",
        }
    )
    env.pop("AGENT_TOKEN_FILE", None)
    if redis_url is not None:
        env["REDIS_URL"] = redis_url
    token2 = ""
    if second_robot:
        token2 = secrets.token_urlsafe(24)
        (var_dir / "agent-2-token").write_text(token2)
        env["AGENT_TOKENS"] = f"mobile-2={token2}"
    standin_port = free_port() if with_scheduler else None
    if standin_port is not None:
        env["SCHEDULER_URL"] = f"http://127.0.0.1:{standin_port}"
        env["SCHEDULER_SYNC_INTERVAL_S"] = "1"
    env.update(extra_env or {})
    specs = system_processes(
        python=python(),
        portal_port=web_port,
        streams_port=streams_port,
        agent_port=agent_port,
        var_dir=var_dir,
        second_agent_port=second_port,
        standin_port=standin_port,
        standin_test_control=True,
    )
    stack = Stack(specs, env)
    stack.web = f"http://127.0.0.1:{web_port}"
    stack.streams = f"http://127.0.0.1:{streams_port}"
    stack.agent_url = f"http://127.0.0.1:{agent_port}"
    stack.token = token
    stack.agent = AgentClient(stack.agent_url, token)
    if standin_port is not None:
        stack.standin = f"http://127.0.0.1:{standin_port}"
    if second_port is not None:
        stack.agent2_url = f"http://127.0.0.1:{second_port}"
        stack.token2 = token2
        stack.agent2 = AgentClient(stack.agent2_url, token2)
    try:
        for spec in specs:
            stack.start(spec.name)
        for name in stack.specs:
            if name != "beat":
                stack.wait_ready(name)
        yield stack
    finally:
        stack.stop()


@pytest.fixture
def stack(tmp_path):
    """Agent, ASGI web server, Celery workers and beat on the test database and Redis."""
    with running_stack(tmp_path / "var", broker_url=settings.CELERY_BROKER_URL) as running:
        yield running


@pytest.fixture
def stack_with_scheduler(tmp_path):
    """The same, with the stand-in scheduler (its test controls on) owning the fixed nodes,
    swept every second."""
    with running_stack(
        tmp_path / "var", broker_url=settings.CELERY_BROKER_URL, with_scheduler=True
    ) as running:
        yield running


# What the fault tests need to see their faults through in seconds, not minutes.
FAULT_ENV = {
    "HEALTH_POLL_INTERVAL_S": "1",
    # An agent killed on purpose comes back long before this: no hold from those tests.
    "HEALTH_UNREACHABLE_S": "120",
    "RUN_START_GRACE_S": "3",
    "RUN_COLLECT_GRACE_S": "120",
}


@pytest.fixture(scope="module")
def fault_stack(tmp_path_factory, django_db_setup):
    """One system per module on a private Redis server, with two robots, to break on purpose.

    After the test database is made (``django_db_setup``): the processes are pointed at it.
    """
    base = tmp_path_factory.mktemp("fault-stack")
    server = RedisServer(base / "redis")
    server.start()
    try:
        with running_stack(
            base / "var",
            broker_url=server.url(1),
            redis_url=server.url(0),
            second_robot=True,
            extra_env=FAULT_ENV,
        ) as running:
            running.redis = server
            yield running
    finally:
        server.stop()
