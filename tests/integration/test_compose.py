"""The production profile, run: every service of ``docker-compose.yml`` started as a process
with the command and environment the file gives it (as ``docker-compose config`` resolves
them), in production mode, without a container runtime.

What stands in for the containers: the secrets are files in a folder of the test's own
(``/run/secrets/NAME``), each service's ``/var/lib/amazing`` and the image's ``/app`` are
folders of its own, the service host names point at 127.0.0.1 on free ports, the
``postgres`` service is the machine's PostgreSQL (a scratch database, as its superuser), and
``redis`` is the service's own ``redis-server`` command on a private port. The nginx proxy
(an image with no command of ours) is left out: requests go to the web and streams servers.

Then what an operator does after ``docker-compose up``: ``testbed_setup``,
``createsuperuser`` and an API token; the portal answers ``/healthz`` healthy, a booked run
completes on the simulated robot, every process logs JSON lines, a worker's request id is in
the agent's line for the call it made, and ``/metrics`` parses.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
import requests
import yaml
from django.conf import settings
from django.utils import timezone
from prometheus_client.parser import text_string_to_metric_families

from bench.stack import REPO, Proc, free_port, wait_http

pytestmark = pytest.mark.integration

COMPOSE = "/usr/bin/docker-compose"
# Started after the migration job, in this order; "migrate" runs to its end first.
LONG_RUNNING = ("agent", "web", "streams", "worker", "mail", "collector", "beat")
# Images whose command is not ours: the machine's servers stand in (see the docstring).
STAND_INS = ("postgres", "proxy")
SECRETS = (
    "django_secret_key",
    "postgres_password",
    "agent_token",
    "agent_read_token",
    "metrics_token",
)
# Started only on demand (``--profile monitoring``): not part of this deployment.
ON_DEMAND = ("prometheus",)
SEGMENT_S = 3.0


def _resolved_compose(operator_env: dict[str, str]) -> dict[str, Any]:
    """The compose file as docker-compose itself resolves it (anchors, ``${…:-…}``)."""
    done = subprocess.run(
        [COMPOSE, "-f", str(REPO / "docker-compose.yml"), "config"],
        cwd=REPO,
        env={**os.environ, **operator_env},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    resolved = yaml.safe_load(done.stdout)
    assert isinstance(resolved, dict)
    return resolved


def _image_env() -> dict[str, str]:
    """The ``ENV`` of the Dockerfile's final stage (what every service inherits)."""
    stage = (REPO / "Dockerfile").read_text().rsplit("\nFROM ", 1)[1]
    env: dict[str, str] = {}
    for line in re.findall(r"^ENV (.+)$", stage, flags=re.M):
        env.update(item.split("=", 1) for item in line.split())
    return env


class Deployment:
    """The compose services as processes on this machine."""

    def __init__(self, compose: dict[str, Any], base: Path, database: str) -> None:
        self.services: dict[str, Any] = compose["services"]
        self.base = base
        self.secrets = base / "secrets"
        self.ports = {"redis": free_port(), "agent": free_port()}
        self.ports |= {"web": free_port(), "streams": free_port()}
        self.database = database
        self.procs: dict[str, Proc] = {}
        self.image_env = _image_env()

    # -- what stands in for the containers --------------------------------------------------

    def _path(self, service: str, value: str) -> str:
        value = re.sub(r"/run/secrets/(\w+)", lambda m: str(self.secrets / m.group(1)), value)
        value = value.replace("/var/lib/amazing", str(self.base / service / "var"))
        return re.sub(r"^/app(?=/|$)", str(self.base / service / "app"), value)

    def _hosts(self, value: str) -> str:
        """Service host names to 127.0.0.1, on the port each got here."""
        if value.startswith("postgres://"):
            url = urlsplit(value)
            assert url.hostname == "postgres", value
            db = settings.DATABASES["default"]
            return f"postgres://{db['USER']}@127.0.0.1:{db['PORT']}/{self.database}"
        for name, port in self.ports.items():
            value = re.sub(rf"\b{name}:\d+", f"127.0.0.1:{port}", value)
        return value

    def _argv(self, service: str) -> list[str]:
        argv = [self._hosts(self._path(service, str(a))) for a in self.services[service]["command"]]
        binary = Path(sys.executable).parent
        argv[0] = sys.executable if argv[0] == "python" else str(binary / argv[0])
        port = self.ports.get(service)
        for i, arg in enumerate(argv):
            if arg == "0.0.0.0":  # noqa: S104 (what the file says; replaced here)
                argv[i] = "127.0.0.1"
            elif re.fullmatch(r"0\.0\.0\.0:\d+", arg):
                argv[i] = f"127.0.0.1:{port}"
            elif i > 0 and argv[i - 1] == "--port":
                argv[i] = str(port)
        return argv

    def env(self, service: str) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(_NOT_INHERITED)}
        env.update({k: self._path(service, v) for k, v in self.image_env.items()})
        for key, value in (self.services[service].get("environment") or {}).items():
            env[key] = self._hosts(self._path(service, str(value)))
        for folder in ("var", "app/static"):
            (self.base / service / folder).mkdir(parents=True, exist_ok=True)
        return env

    # -- running ------------------------------------------------------------------------------

    def start(self, service: str) -> Proc:
        self.procs[service] = Proc(service, self._argv(service), self.env(service))
        return self.procs[service]

    def start_redis(self) -> None:
        argv = [str(a) for a in self.services["redis"]["command"]]
        argv[0] = "/usr/bin/redis-server"
        redis_dir = self.base / "redis"
        redis_dir.mkdir()
        argv += ["--port", str(self.ports["redis"]), "--bind", "127.0.0.1", "--dir", str(redis_dir)]
        self.procs["redis"] = proc = Proc("redis", argv, dict(os.environ))
        proc.wait_for_line(lambda line: "Ready to accept connections" in line, 30)

    def run(self, service: str, *args: str, env: dict[str, str] | None = None) -> str:
        """``docker-compose run --rm SERVICE ARGS`` (or the service's command): to its end."""
        argv = self._argv(service) if not args else [sys.executable, *args]
        argv = [self._hosts(a) for a in argv]
        done = subprocess.run(
            argv,
            cwd=REPO,
            env={**self.env(service), **(env or {})},
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, f"{service} {args}: {done.stdout}\n{done.stderr}"
        return done.stdout

    def url(self, service: str) -> str:
        return f"http://127.0.0.1:{self.ports[service]}"

    def output(self) -> str:
        return "\n".join(p.output(40) for p in self.procs.values())

    def stop(self) -> None:
        """Every process at once, as ``docker-compose down`` does (each waited for)."""
        with ThreadPoolExecutor(len(self.procs) or 1) as pool:
            list(pool.map(lambda proc: proc.stop(), self.procs.values()))


# The test run's own settings are not the deployment's.
_NOT_INHERITED = (
    "DJANGO_",
    "DATABASE_",
    "REDIS_URL",
    "CELERY_",
    "AGENT_",
    "AMAZING_",
    "METRICS_",
    "LOG_",
    "PROMETHEUS_",
    "WEB_",
    "SCHEDULER_",
    "LIVE_",
)


@pytest.fixture
def scratch_database() -> Iterator[str]:
    db = settings.DATABASES["default"]
    name = f"{db['NAME']}_compose"
    where = ["-h", db["HOST"], "-p", str(db["PORT"]), "-U", db["USER"]]
    subprocess.run(["dropdb", *where, "--if-exists", "--force", name], check=True)
    subprocess.run(["createdb", *where, name], check=True)
    try:
        yield name
    finally:
        subprocess.run(["dropdb", *where, "--if-exists", "--force", name], check=True)


@pytest.fixture
def deployment(tmp_path: Path, scratch_database: str) -> Iterator[Deployment]:
    compose = _resolved_compose({"DJANGO_ALLOWED_HOSTS": "127.0.0.1"})
    assert set(compose["services"]) == {"redis", "migrate", *LONG_RUNNING, *STAND_INS, *ON_DEMAND}
    assert set(compose["secrets"]) == set(SECRETS)
    deployed = Deployment(compose, tmp_path, scratch_database)
    deployed.secrets.mkdir()
    for name in SECRETS:
        (deployed.secrets / name).write_text(os.urandom(24).hex() + "\n")
    try:
        deployed.start_redis()
        deployed.run("migrate")
        for service in LONG_RUNNING:
            deployed.start(service)
        yield deployed
    finally:
        deployed.stop()


def _wait_ready(deployed: Deployment) -> None:
    running = list(deployed.procs.values())
    for service in ("agent", "web", "streams"):
        wait_http(f"{deployed.url(service)}/healthz", 90, running)
    deployed.procs["worker"].wait_for_line(lambda line: "ready." in line, 90)


def _json_lines(proc: Proc) -> list[dict[str, Any]]:
    """Every line a process wrote; each must be one JSON object (production logs)."""
    parsed = []
    for line in proc.lines:
        if not line.strip():
            continue
        try:
            parsed.append(json.loads(line))
        except ValueError:
            raise AssertionError(f"{proc.name} wrote a line that is not JSON: {line!r}") from None
    return parsed


def test_the_compose_services_run_in_production_mode_and_a_booked_run_completes(
    deployment: Deployment,
):
    web = deployment.url("web")
    # What an operator does after `docker-compose up` (docs/operations.md, bring-up), while
    # the services start.
    deployment.run("web", "manage.py", "testbed_setup", "--agent-url", "http://agent:8700")
    password = os.urandom(12).hex()
    deployment.run(
        "web",
        "manage.py",
        "createsuperuser",
        "--no-input",
        "--username",
        "ops",
        "--email",
        "ops@example.org",
        env={"DJANGO_SUPERUSER_PASSWORD": password},
    )
    # An experimenter's account and API token (a staff account's token would need MFA).
    deployment.run(
        "web",
        "manage.py",
        "shell",
        "-c",
        "from core.accounts.models import User; User.objects.create_user('erin')",
    )
    printed = deployment.run("web", "manage.py", "api_token", "create", "erin", "--name", "compose")
    token = re.search(r"^(amz_\w+)$", printed, re.MULTILINE)
    assert token, printed
    headers = {"Authorization": f"Token {token.group(1)}"}
    _wait_ready(deployment)

    experiment = requests.post(
        f"{web}/api/v1/experiments/",
        json={
            "title": "compose profile",
            "segments": [{"velocity_mps": 0.5, "direction": "cw", "duration_s": SEGMENT_S}],
        },
        headers=headers,
        timeout=10,
    )
    assert experiment.status_code == 201, experiment.text
    start = timezone.now() + timedelta(seconds=6)
    booking = requests.post(
        f"{web}/api/v1/reservations/",
        json={
            "resource": "mobile-1",
            "experiment": experiment.json()["id"],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(seconds=SEGMENT_S + 4)).isoformat(),
        },
        headers={**headers, "X-Request-ID": "compose-booking-1"},
        timeout=10,
    )
    assert booking.status_code == 201, booking.text
    assert booking.headers["X-Request-ID"] == "compose-booking-1"
    run_id = booking.json()["run"]["id"]

    run: dict[str, Any] = {}
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        run = requests.get(f"{web}/api/v1/runs/{run_id}/", headers=headers, timeout=10).json()
        if run["state"] in ("completed", "failed", "interrupted", "cancelled"):
            break
        time.sleep(0.5)
    assert run["state"] == "completed", f"{run}\n{deployment.output()}"
    assert run["sample_count"] == run["agent_sample_count"] >= SEGMENT_S * 20
    health = requests.get(f"{web}/healthz", timeout=10)
    assert health.status_code == 200, health.text
    assert health.json()["status"] == "ok"
    assert health.json()["scheduler"]["ok"] is True  # beat and a worker sweep

    # Production logs: JSON lines everywhere (the servers' own lines too), and the staging
    # call's request id in the agent's line and in the worker's lines of that task.
    lines = {name: _json_lines(deployment.procs[name]) for name in LONG_RUNNING}
    assert any(line["logger"] == "portal.access" for line in lines["web"])
    booked = [line for line in lines["web"] if line.get("request_id") == "compose-booking-1"]
    assert any(line.get("path") == "/api/v1/reservations/" for line in booked), booked
    staged = [
        line
        for line in lines["agent"]
        if line.get("method") == "PUT" and line.get("path") == f"/api/v1/runs/run-{run_id}"
    ]
    assert staged, lines["agent"][-20:]
    staging_id = staged[0]["request_id"]
    assert any(line.get("request_id") == staging_id for line in lines["worker"]), staging_id

    metrics_token = (deployment.secrets / "metrics_token").read_text().strip()
    scrape = requests.get(
        f"{web}/metrics", headers={"Authorization": f"Bearer {metrics_token}"}, timeout=10
    )
    assert scrape.status_code == 200
    found = {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(scrape.text)
        for sample in family.samples
    }
    assert found[("amazing_runs", (("state", "completed"),))] == 1
    assert found[("amazing_scheduler_link_errors_total", ())] == 0
    assert found[("amazing_resource_held", (("resource", "mobile-1"),))] == 0


def _vendor_files(text: str, target: str) -> set[str]:
    """The front-end files (vendor folder / file name) a build recipe copies under ``target``."""
    files: set[str] = set()
    for line in text.replace("\\\n", " ").splitlines():
        words = line.split()
        if not words or words[0] not in {"cp", "COPY"} or not words[-1].startswith(target):
            continue
        folder = words[-1].removeprefix(target).strip("/")
        for source in words[1:-1]:
            if source.startswith("--"):
                continue
            _, _, rest = source.rpartition("/")
            # The Makefile's shell reads {a,b} as two names; Docker's COPY takes no such thing.
            match = re.fullmatch(r"(.*)\{(.+)\}(.*)", rest)
            names = (
                [match[1] + part + match[3] for part in match[2].split(",")] if match else [rest]
            )
            files |= {f"{folder}/{name}" for name in names}
    return files


def test_the_image_holds_every_front_end_file_make_setup_copies() -> None:
    """The pages load their libraries from var/assets/vendor: a library the Makefile copies and
    the Dockerfile forgets is a page that works under ``make run`` and is blank in production."""
    made = _vendor_files((REPO / "Makefile").read_text(), "$(ASSETS)/vendor/")
    imaged = _vendor_files((REPO / "Dockerfile").read_text(), "var/assets/vendor/")
    assert made, "no front-end files found in the Makefile's asset rule"
    assert imaged == made
