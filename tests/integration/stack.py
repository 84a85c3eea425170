"""The system's processes as a pytest fixture: agent, ASGI web server, Celery worker and beat."""

from __future__ import annotations

import os
import secrets

import pytest
import redis
from django.conf import settings

from basestation.client import AgentClient
from tests.integration.processes import Proc, free_port, python, wait_http


@pytest.fixture
def stack(tmp_path):
    """Agent, ASGI web server, Celery worker and beat on the test database and Redis."""
    db = settings.DATABASES["default"]
    assert db["ENGINE"].endswith("postgresql"), "the integration test runs on PostgreSQL"
    broker_url = settings.CELERY_BROKER_URL
    assert broker_url.startswith("redis://"), "the integration test runs on Redis"
    redis.Redis.from_url(broker_url).flushdb()

    token = secrets.token_urlsafe(24)
    agent_port, web_port = free_port(), free_port()
    env = dict(os.environ)
    env.update(
        {
            "DJANGO_DEBUG": "1",
            "DATABASE_URL": f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}",
            "CELERY_BROKER_URL": broker_url,
            "AGENT_TOKEN": token,
            "AGENT_DATA_DIR": str(tmp_path / "agent"),
            "AMAZING_VAR_DIR": str(tmp_path / "var"),
            "RUN_SWEEP_INTERVAL_S": "0.5",
            "PYTHONUNBUFFERED": "1",
        }
    )
    procs = [
        Proc("agent", [python(), "-m", "basestation", "--port", str(agent_port)], env),
        Proc(
            "web",
            [python(), "-m", "uvicorn", "portal.asgi:application", "--port", str(web_port)],
            env,
        ),
        Proc(
            "worker",
            [
                python(),
                "-m",
                "celery",
                "-A",
                "portal",
                "worker",
                "--pool",
                "threads",
                "--concurrency",
                "4",
                "--loglevel",
                "INFO",
                "--without-mingle",
                "--without-gossip",
            ],
            env,
        ),
        Proc(
            "beat",
            [
                python(),
                "-m",
                "celery",
                "-A",
                "portal",
                "beat",
                "--loglevel",
                "INFO",
                "--schedule",
                str(tmp_path / "beat-schedule"),
            ],
            env,
        ),
    ]
    try:
        wait_http(f"http://127.0.0.1:{agent_port}/healthz", 30, procs)
        wait_http(f"http://127.0.0.1:{web_port}/accounts/login/", 30, procs)
        procs[2].wait_for_line(lambda line: "ready." in line, 30)
        yield {
            "web": f"http://127.0.0.1:{web_port}",
            "agent": AgentClient(f"http://127.0.0.1:{agent_port}", token),
            "agent_url": f"http://127.0.0.1:{agent_port}",
            "token": token,
            "procs": procs,
        }
    finally:
        for proc in reversed(procs):
            proc.stop()
