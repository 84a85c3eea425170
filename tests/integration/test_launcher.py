"""``make run``'s launcher, as a user meets it: embedded defaults, log in, book, stop."""

from __future__ import annotations

import os
import re
import signal
import time
from collections.abc import Iterator
from datetime import timedelta

import pytest
import requests
from django.utils import timezone

from bench.stack import Proc, free_port, python
from tests.integration.processes import processes_matching_env

pytestmark = [pytest.mark.integration, pytest.mark.long]


def _csrf(session: requests.Session, url: str) -> str:
    page = session.get(url, timeout=10)
    assert page.status_code == 200, page.text[:500]
    match = re.search(r'name="csrfmiddlewaretoken" value="([^"]+)"', page.text)
    assert match, f"no CSRF token on {url}"
    return match.group(1)


def _json(session: requests.Session, url: str, launcher: Proc) -> dict:
    """``url``'s JSON; if the portal is gone, fail with what its processes said."""
    try:
        return session.get(url, timeout=10).json()
    except requests.ConnectionError as exc:
        raise AssertionError(f"{url}: {exc}\n{launcher.output(200)}") from exc


def _wait_ended(session: requests.Session, data_url: str, launcher: Proc) -> dict:
    """The run page's data once the run is no longer live (60 s at most)."""
    deadline = time.monotonic() + 60
    data: dict = {}
    while time.monotonic() < deadline:
        data = _json(session, data_url, launcher)
        if not data["live"]:
            break
        time.sleep(0.5)
    return data


def _pid_of(launcher: Proc, name: str) -> int:
    """The pid the launcher last started ``name`` with."""
    started = [s for s in launcher.lines if f"started {name} (pid " in s]
    assert started, f"{name} was never started\n{launcher.output()}"
    return int(started[-1].rsplit("(pid ", 1)[1].rstrip(")"))


def test_the_launcher_runs_the_whole_system_and_stops_every_child(tmp_path):
    var_dir = tmp_path / "var"
    portal_port, agent_port, standin_port = free_port(), free_port(), free_port()
    streams_port = free_port()
    env = {
        k: v
        for k, v in os.environ.items()
        # The embedded defaults: no external database or broker.
        if k
        not in {
            "DATABASE_URL",
            "CELERY_BROKER_URL",
            "REDIS_URL",
            "AGENT_TOKEN",
            "AGENT_TOKEN_FILE",
            "SCHEDULER_URL",
        }
    }
    env.update(
        {
            "AMAZING_VAR_DIR": str(var_dir),
            "PORTAL_PORT": str(portal_port),
            "STREAMS_PORT": str(streams_port),
            "AGENT_PORT": str(agent_port),
            "STANDIN_PORT": str(standin_port),
            "RUN_SWEEP_INTERVAL_S": "0.5",
        }
    )
    launcher = Proc("launch", [python(), "-m", "portal.launcher"], env)
    try:
        line = launcher.wait_for_line(lambda s: "demo user created: experimenter" in s, 90)
        password = line.split("password: ")[1].strip()
        launcher.wait_for_line(lambda s: "ready: log in at" in s, 90)
        assert any("SQLite" in s for s in launcher.lines)
        assert any("filesystem (no server)" in s for s in launcher.lines)
        assert any(f"127.0.0.1:{standin_port} (the stand-in)" in s for s in launcher.lines)

        web = f"http://127.0.0.1:{portal_port}"
        session = requests.Session()
        token = _csrf(session, f"{web}/accounts/login/")
        login = session.post(
            f"{web}/accounts/login/",
            data={"csrfmiddlewaretoken": token, "login": "experimenter", "password": password},
            headers={"Referer": f"{web}/accounts/login/"},
            timeout=10,
        )
        assert login.status_code == 200
        assert "Hello, experimenter" in login.text, login.text[:2000]

        token = _csrf(session, f"{web}/experiments/new/")
        saved = session.post(
            f"{web}/experiments/new/",
            data={
                "csrfmiddlewaretoken": token,
                "title": "launcher check",
                "velocity_mps": ["0.6", "0.4", ""],
                "direction": ["cw", "ccw", "cw"],
                "duration_s": ["2", "2", ""],
            },
            timeout=10,
        )
        assert "Experiment “launcher check” saved." in saved.text, saved.text[:3000]
        experiment_id = re.search(r'href="/book/\?experiment=(\d+)"', saved.text).group(1)

        token = _csrf(session, f"{web}/book/")
        # With its UTC offset: a bare wall-clock time in the hour the clocks pass twice names
        # the first pass, an hour ago during the second.
        start = (timezone.now() + timedelta(seconds=5)).replace(microsecond=0)
        booked = session.post(
            f"{web}/book/",
            data={
                "csrfmiddlewaretoken": token,
                "resources": "mobile-1",
                "experiment": experiment_id,
                "start_at": start.isoformat(),
                "end_at": (start + timedelta(seconds=8)).isoformat(),
            },
            timeout=10,
        )
        assert booked.status_code == 200
        assert "/runs/" in booked.url, booked.text[:3000]
        data_url = booked.url.rstrip("/") + "/data.json"

        data = _wait_ended(session, data_url, launcher)
        assert data["state"] == "completed", (
            f"{data.get('state')}: {data.get('reason')}\n{launcher.output(120)}"
        )
        # "completed": every sample the agent recorded was collected. How many the loop
        # recorded is its rate, which a busy machine lowers and `make bench` measures.
        assert data["sample_count"] > 0
        assert len(data["series"]["measured_mps"]["t"]) == data["sample_count"]
        assert "segment-stats" in data["analysis_html"]
        # The demo's node measured it: its synthetic signal strength was pushed while it ran,
        # placed in the rail's grid cells (the heatmap's numbers) on the run page.
        run_id = booked.url.rstrip("/").rsplit("/", 1)[1]
        launcher.wait_for_line(lambda s: f"readings sent to run {run_id}'s series rssi" in s, 60)
        series = session.get(f"{booked.url.rstrip('/')}/measurements/series/", timeout=10)
        assert 'id="measurement-rssi"' in series.text, series.text[:3000]
        assert "data-cell=" in series.text, series.text[:3000]
        # The run went through, so beat and the worker swept; the web process sees it.
        health = requests.get(f"{web}/healthz", timeout=10).json()
        assert health["status"] == "ok", health
        assert health["scheduler"]["ok"], health
        assert health["testbed_scheduler"]["configured"], health

        # A fixed node is the stand-in scheduler's: booking it holds a lease there.
        token = _csrf(session, f"{web}/book/")
        later = start + timedelta(days=1)
        fixed = session.post(
            f"{web}/book/",
            data={
                "csrfmiddlewaretoken": token,
                "resources": "node-01",
                "start_at": later.isoformat(),
                "end_at": (later + timedelta(hours=1)).isoformat(),
            },
            timeout=20,
        )
        assert "Booked node-01" in fixed.text, fixed.text[:3000]
        leases = requests.get(
            f"http://127.0.0.1:{standin_port}/resources/leases", timeout=10
        ).json()["resource_response"]["resources"]
        assert [[c["name"] for c in lease["components"]] for lease in leases] == [["node-01"]]

        # A child that dies is started again; the rest go on serving meanwhile.
        worker_pid = _pid_of(launcher, "worker")
        since = launcher.mark()
        os.killpg(worker_pid, signal.SIGKILL)
        launcher.wait_for_line(
            lambda s: "worker exited with code -9; starting it again" in s, 30, since=since
        )
        assert requests.get(f"{web}/healthz", timeout=10).status_code == 200
        launcher.wait_for_line(lambda s: "started worker (pid" in s, 30, since=since)
        assert _pid_of(launcher, "worker") != worker_pid
        launcher.wait_for_line(lambda s: s.startswith("worker") and " ready." in s, 60, since=since)
        # The new worker does the work: a second run completes.
        token = _csrf(session, f"{web}/book/")
        # With its UTC offset: a bare wall-clock time in the hour the clocks pass twice names
        # the first pass, an hour ago during the second.
        start = (timezone.now() + timedelta(seconds=5)).replace(microsecond=0)
        booked = session.post(
            f"{web}/book/",
            data={
                "csrfmiddlewaretoken": token,
                "resources": "mobile-1",
                "experiment": experiment_id,
                "start_at": start.isoformat(),
                "end_at": (start + timedelta(seconds=8)).isoformat(),
            },
            timeout=10,
        )
        assert "/runs/" in booked.url, booked.text[:3000]
        data = _wait_ended(session, booked.url.rstrip("/") + "/data.json", launcher)
        assert data["state"] == "completed", f"{data['reason']}\n{launcher.output(1500)}"
        assert not any("stopping the rest" in s for s in launcher.lines)

        assert processes_matching_env("AMAZING_VAR_DIR", str(var_dir)), "children should be running"
        launcher.popen.send_signal(signal.SIGINT)
        assert launcher.popen.wait(timeout=30) == 0, launcher.output()
    finally:
        launcher.stop(signal.SIGKILL)
        leftover = processes_matching_env("AMAZING_VAR_DIR", str(var_dir))
        for pid in leftover:
            os.kill(pid, signal.SIGKILL)
    assert not leftover, f"processes left behind: {leftover}\n{launcher.output()}"
    assert any("all processes stopped" in s for s in launcher.lines)


def _sse_names(lines: Iterator[str], until: str, timeout_s: float) -> list[str]:
    """The ``event:`` names of an open live stream's ``lines``, read until a state ``until``."""
    names: list[str] = []
    deadline = time.monotonic() + timeout_s
    for line in lines:
        if line and line.startswith("data:") and f'"state":"{until}"' in line:
            names.append(until)
            return names
        if line and line.startswith("event:"):
            names.append(line.split(":", 1)[1].strip())
            if until == "open" and names[-1] == "open":
                return names
        if time.monotonic() > deadline:
            break
    raise AssertionError(f"no {until}: saw {names}")


def test_make_run_starts_two_robots_and_pushes_live_without_redis(tmp_path):
    """ROBOTS=2: a second agent and robot on a second rail; runs on both at once; the run
    page's stream works on the embedded setup (no Redis: files under var/live)."""
    var_dir = tmp_path / "var"
    portal_port, agent_port, second_port = free_port(), free_port(), free_port()
    streams_port = free_port()
    env = {
        k: v
        for k, v in os.environ.items()
        if k
        not in {"DATABASE_URL", "CELERY_BROKER_URL", "REDIS_URL", "AGENT_TOKEN", "AGENT_TOKEN_FILE"}
    }
    env.update(
        {
            "AMAZING_VAR_DIR": str(var_dir),
            "PORTAL_PORT": str(portal_port),
            "STREAMS_PORT": str(streams_port),
            "AGENT_PORT": str(agent_port),
            "AGENT_2_PORT": str(second_port),
            "ROBOTS": "2",
            "RUN_SWEEP_INTERVAL_S": "0.5",
        }
    )
    launcher = Proc("launch", [python(), "-m", "portal.launcher"], env)
    try:
        line = launcher.wait_for_line(lambda s: "demo user created: experimenter" in s, 90)
        password = line.split("password: ")[1].strip()
        launcher.wait_for_line(lambda s: "ready: log in at" in s, 90)
        assert any(f"live updates: files in {var_dir / 'live'}" in s for s in launcher.lines)
        launcher.wait_for_line(lambda s: s.startswith("agent-2"), 60)

        web = f"http://127.0.0.1:{portal_port}"
        session = requests.Session()
        token = _csrf(session, f"{web}/accounts/login/")
        session.post(
            f"{web}/accounts/login/",
            data={"csrfmiddlewaretoken": token, "login": "experimenter", "password": password},
            headers={"Referer": f"{web}/accounts/login/"},
            timeout=10,
        )
        token = _csrf(session, f"{web}/experiments/new/")
        saved = session.post(
            f"{web}/experiments/new/",
            data={
                "csrfmiddlewaretoken": token,
                "title": "two rails",
                "velocity_mps": ["0.5", ""],
                "direction": ["cw", "cw"],
                "duration_s": ["3", ""],
            },
            timeout=10,
        )
        experiment_id = re.search(r'href="/book/\?experiment=(\d+)"', saved.text).group(1)
        # With its UTC offset, as above. Far enough ahead that the second run's stream is open
        # before it starts on a busy machine: a stream tells only what happens after it opens.
        start = (timezone.now() + timedelta(seconds=15)).replace(microsecond=0)

        def book(resource: str) -> str:
            token = _csrf(session, f"{web}/book/")
            booked = session.post(
                f"{web}/book/",
                data={
                    "csrfmiddlewaretoken": token,
                    "resources": resource,
                    "experiment": experiment_id,
                    "start_at": start.isoformat(),
                    "end_at": (start + timedelta(seconds=6)).isoformat(),
                },
                timeout=10,
            )
            assert "/runs/" in booked.url, booked.text[:3000]
            return booked.url.rstrip("/")

        second_url = book("mobile-2")
        run_id = second_url.rsplit("/", 1)[1]
        stream_url = f"http://127.0.0.1:{streams_port}/live/runs/{run_id}/"
        with session.get(stream_url, stream=True, timeout=(5, 60)) as response:
            assert response.status_code == 200, response.text[:500]
            assert response.headers["Content-Type"] == "text/event-stream"
            lines = response.iter_lines(decode_unicode=True)
            assert _sse_names(lines, "open", 10) == ["open"]
            data = _json(session, f"{second_url}/data.json", launcher)
            state = data["state"]
            assert state in ("scheduled", "staged"), f"began before its stream opened: {data}"
            run_urls = [book("mobile-1"), second_url]
            events = ["open", *_sse_names(lines, "completed", 60)]
        assert "samples" in events
        for url in run_urls:  # the other robot's run ends on its own, about as soon
            deadline = time.monotonic() + 30
            data = _json(session, f"{url}/data.json", launcher)
            while data["live"] and time.monotonic() < deadline:
                time.sleep(0.5)
                data = _json(session, f"{url}/data.json", launcher)
            assert data["state"] == "completed", f"{url}: {data['reason']}\n{launcher.output()}"
            assert data["sample_count"] > 0
        rails = {_json(session, f"{url}/data.json", launcher)["rail_length_m"] for url in run_urls}
        assert len(rails) == 2  # two robots, two rails

        # Ctrl-C, then a burst of SIGTERMs (a supervisor's stop on top): signals arriving
        # while the handler of the one before runs must still stop it, not hang it.
        launcher.popen.send_signal(signal.SIGINT)
        for _ in range(500):
            try:
                os.kill(launcher.popen.pid, signal.SIGTERM)
            except ProcessLookupError:
                break
        assert launcher.popen.wait(timeout=30) == 0, launcher.output()
    finally:
        launcher.stop(signal.SIGKILL)
        leftover = processes_matching_env("AMAZING_VAR_DIR", str(var_dir))
        for pid in leftover:
            os.kill(pid, signal.SIGKILL)
    assert not leftover, f"processes left behind: {leftover}\n{launcher.output()}"
