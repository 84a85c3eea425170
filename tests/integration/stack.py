"""The system's processes as a pytest fixture: agent, ASGI web server, Celery worker and beat."""

from __future__ import annotations

import os
import secrets

import pytest
import redis
from django.conf import settings

from basestation.client import AgentClient
from portal.processes import system_processes
from tests.integration.processes import Proc, free_port, python, wait_http


@pytest.fixture
def stack(tmp_path):
    """Agent, ASGI web server, Celery worker and beat on the test database and Redis."""
    yield from _stack(tmp_path)


@pytest.fixture
def stack_with_scheduler(tmp_path):
    """The same, with the stand-in scheduler (its test controls on) owning the fixed nodes,
    swept every second."""
    yield from _stack(tmp_path, with_scheduler=True)


def _stack(tmp_path, *, with_scheduler: bool = False):
    db = settings.DATABASES["default"]
    assert db["ENGINE"].endswith("postgresql"), "the integration test runs on PostgreSQL"
    broker_url = settings.CELERY_BROKER_URL
    assert broker_url.startswith("redis://"), "the integration test runs on Redis"
    redis.Redis.from_url(broker_url).flushdb()

    token = secrets.token_urlsafe(24)
    agent_port, web_port = free_port(), free_port()
    var_dir = tmp_path / "var"
    var_dir.mkdir()
    env = dict(os.environ)
    env.update(
        {
            "DJANGO_DEBUG": "1",
            "DATABASE_URL": f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}",
            "CELERY_BROKER_URL": broker_url,
            "AGENT_TOKEN": token,
            "AGENT_DATA_DIR": str(tmp_path / "agent"),
            "AMAZING_VAR_DIR": str(var_dir),
            "RUN_SWEEP_INTERVAL_S": "0.5",
            "PYTHONUNBUFFERED": "1",
        }
    )
    standin_port = free_port() if with_scheduler else None
    if standin_port is not None:
        env["SCHEDULER_URL"] = f"http://127.0.0.1:{standin_port}"
        env["SCHEDULER_SYNC_INTERVAL_S"] = "1"
    specs = system_processes(
        python=python(),
        portal_port=web_port,
        agent_port=agent_port,
        var_dir=var_dir,
        standin_port=standin_port,
        standin_test_control=True,
    )
    procs: dict[str, Proc] = {}
    try:
        for spec in specs:
            procs[spec.name] = Proc(spec.name, list(spec.argv), {**env, **spec.env})
        running = list(procs.values())
        if standin_port is not None:
            wait_http(f"http://127.0.0.1:{standin_port}/resources/nodes", 30, running)
        wait_http(f"http://127.0.0.1:{agent_port}/healthz", 30, running)
        wait_http(f"http://127.0.0.1:{web_port}/accounts/login/", 30, running)
        procs["worker"].wait_for_line(lambda line: "ready." in line, 30)
        yield {
            "web": f"http://127.0.0.1:{web_port}",
            "agent": AgentClient(f"http://127.0.0.1:{agent_port}", token),
            "agent_url": f"http://127.0.0.1:{agent_port}",
            "token": token,
            "procs": running,
            "by_name": procs,
            "standin": f"http://127.0.0.1:{standin_port}" if standin_port else None,
            "env": env,
        }
    finally:
        for proc in reversed(procs.values()):
            proc.stop()
