"""Many robots: N simulated robots each running a 20 Hz run at once, collected into PostgreSQL.

For each N (1, 4, 8 by default) the system's collection path runs as in production
(``portal.processes``): N agents, each with its simulated robot, its own store and port; one
Celery worker for the runs queue; the collector; beat at its default sweep interval; a private
redis-server (broker and live bus) and a scratch PostgreSQL database. One run per robot is
booked, all starting at the same instant.

- **Collection lag** of a sample: when its ``samples`` event was published (right after the
  commit that stored it in PostgreSQL; heard on Redis) minus its ``t`` (the agent's clock at
  the control tick that recorded it; same machine, same clock).
- **CPU** of the collector and of the worker: user + system seconds over the programs'
  length (``/proc/<pid>/stat``), as a share of one core, and per robot.
- Every run must end ``completed`` with each of the agent's samples stored once.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import timedelta
from functools import partial
from pathlib import Path

import redis
import requests

from basestation.client import AgentClient
from bench.stack import Proc, RedisServer, free_port, wait_until
from bench.stats import percentile

REPO = Path(__file__).resolve().parent.parent
HZ = 20.0
ROBOTS = (1, 4, 8)
PROGRAM_S = 30.0
LEAD_S = 10.0  # booking to start: staged by the next sweeps, followed by the collector
LAG_TARGET_S = 1.0
CLK_TCK = os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process and its reaped children so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    # After the ")": state is field 3 of stat(5); utime, stime, cutime, cstime are 14-17.
    return sum(int(fields[i]) for i in range(11, 15)) / CLK_TCK


def _healthy(url: str) -> bool:
    return requests.get(url, timeout=2).ok


class _Announcements:
    """Every ``samples`` event on the runs' channels, with when it was heard."""

    def __init__(self, redis_url: str) -> None:
        from core.live import redis_channel  # after django.setup(): this database's channels

        self._pubsub = redis.Redis.from_url(redis_url).pubsub(ignore_subscribe_messages=True)
        self._pubsub.psubscribe(redis_channel("run-*"))
        self.heard: dict[int, dict[int, float]] = {}  # run id -> seq -> when
        self.repeats = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._listen, daemon=True)
        self._thread.start()

    def _listen(self) -> None:
        while not self._stop.is_set():
            message = self._pubsub.get_message(timeout=0.2)
            if message is None or message["type"] != "pmessage":
                continue
            at_s = time.time()
            event = json.loads(message["data"])
            if event.get("type") != "samples":
                continue
            run_id = int(message["channel"].decode().rsplit("-", 1)[1])
            seen = self.heard.setdefault(run_id, {})
            for seq in range(int(event["first_seq"]), int(event["last_seq"]) + 1):
                if seq in seen:
                    self.repeats += 1
                else:
                    seen[seq] = at_s

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._pubsub.close()


@dataclass(frozen=True)
class Round:
    robots: int
    samples: int
    lag_p50_s: float
    lag_p95_s: float
    lag_max_s: float
    collector_cpu: float  # share of one core over the programs' length
    worker_cpu: float
    agents_cpu: float  # all agents together
    exact: bool  # every run completed, each of its samples stored and announced once

    def row(self) -> str:
        per = self.robots
        return (
            f"| {self.robots} | {self.samples} | {self.lag_p50_s * 1000:.0f} ms "
            f"| {self.lag_p95_s * 1000:.0f} ms | {self.lag_max_s * 1000:.0f} ms "
            f"| {self.collector_cpu:.1%} ({self.collector_cpu / per:.1%}) "
            f"| {self.worker_cpu:.1%} ({self.worker_cpu / per:.1%}) "
            f"| {self.agents_cpu / per:.1%} | {'yes' if self.exact else 'NO'} |"
        )


def _round(
    *,
    robots: int,
    program_s: float,
    env: dict[str, str],
    redis_url: str,
    work: Path,
    token: str,
) -> Round:
    from django.db import connections
    from django.utils import timezone

    from bookings.models import Resource
    from core.accounts.models import User
    from portal.experiments.models import Experiment
    from portal.processes import (
        agent_process,
        beat_process,
        collector_process,
        worker_process,
    )
    from portal.runs.models import Run, Sample
    from portal.runs.services.reservations import reservation_create
    from portal.runs.states import RUN_END_STATES

    python = sys.executable
    round_dir = work / f"n{robots}"
    round_dir.mkdir()
    children: dict[str, Proc] = {}

    def launch(name: str, argv: Sequence[str], env: dict[str, str]) -> None:
        children[name] = Proc(name, list(argv), env, log_path=round_dir / f"{name}.log")

    listener = _Announcements(redis_url)
    try:
        ports = [free_port() for _ in range(robots)]
        for k, port in enumerate(ports, start=1):
            spec = agent_process(python=python, port=port)
            agent_env = {
                **env,
                "AGENT_RESOURCE": f"mobile-{k}",
                "AGENT_DATA_DIR": str(round_dir / f"agent-{k}"),
                "AGENT_CONTROL_HZ": f"{HZ:g}",
            }
            launch(f"agent-{k}", spec.argv, agent_env)
        for spec in (
            worker_process(python=python, log_level="WARNING"),
            collector_process(python=python),
            beat_process(
                python=python, schedule_file=round_dir / "celerybeat-schedule", log_level="WARNING"
            ),
        ):
            launch(spec.name, spec.argv, {**env, **spec.env})
        for port in ports:
            wait_until("an agent", partial(_healthy, f"http://127.0.0.1:{port}/healthz"), 60)
        # The lead is counted from when the worker and beat are up (their banners, printed
        # at any log level): on a busy machine they start seconds after the agents, and a run
        # booked before could pass its start before anything staged it.
        children["worker"].wait_for_line(lambda line: "[queues]" in line, 90)
        children["beat"].wait_for_line(lambda line: "is starting." in line, 90)

        user = User.objects.get_or_create(username="bench-scale")[0]
        start = timezone.now() + timedelta(seconds=LEAD_S)
        run_ids = []
        for k, port in enumerate(ports, start=1):
            robot, _ = Resource.objects.update_or_create(
                name=f"mobile-{k}",
                defaults={
                    "kind": "mobile",
                    "agent_url": f"http://127.0.0.1:{port}",
                    "max_velocity_mps": 2,
                    "max_accel_mps2": 1,
                },
            )
            experiment = Experiment.objects.create(
                owner=user,
                title=f"scale bench, robot {k} of {robots}",
                segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": program_s}],
            )
            reservation = reservation_create(
                owner=user,
                resource=robot,
                start_at=start,
                end_at=start + timedelta(seconds=program_s + 5),
                experiment=experiment,
            )
            run_ids.append(reservation.run.pk)

        pids = {name: proc.popen.pid for name, proc in children.items()}
        # CPU is counted over the programs: from their start to their end.
        time.sleep(max(0.0, (start - timezone.now()).total_seconds()))
        cpu_before = {name: _cpu_s(pid) for name, pid in pids.items()}
        started = time.monotonic()
        time.sleep(program_s)
        elapsed_s = time.monotonic() - started
        cpu = {name: (_cpu_s(pid) - cpu_before[name]) / elapsed_s for name, pid in pids.items()}

        def all_ended() -> bool:
            # A run not staged yet (its sweep late on a busy machine) has not ended either.
            return not Run.objects.filter(pk__in=run_ids).exclude(state__in=RUN_END_STATES).exists()

        wait_until("every run to end", all_ended, 120 + program_s)
        connections.close_all()
        listener.close()

        # A run that never reached its agent (staged too late on a machine too busy, say)
        # has nothing to compare: said so, with the processes' last lines, not a 404.
        unfinished = [
            f"run {run.pk} ended {run.state}: {run.reason or 'no reason given'}"
            for run in Run.objects.filter(pk__in=run_ids).exclude(state="completed")
        ]
        if unfinished:
            raise AssertionError(
                f"{robots} robot(s): "
                + "; ".join(unfinished)
                + "\n"
                + "\n".join(proc.output(30) for proc in children.values())
            )
        lags: list[float] = []
        exact = listener.repeats == 0
        total = 0
        for k, run_id in enumerate(run_ids, start=1):
            run = Run.objects.get(pk=run_id)
            with AgentClient(f"http://127.0.0.1:{ports[k - 1]}", token) as agent:
                on_agent = {
                    int(s["seq"]): float(s["t"]) for s in agent.iter_samples(f"run-{run_id}")
                }
            stored = list(
                Sample.objects.filter(run_id=run_id).order_by("seq").values_list("seq", flat=True)
            )
            heard = listener.heard.get(run_id, {})
            exact = exact and run.state == "completed" and stored == sorted(on_agent)
            exact = exact and set(heard) == set(on_agent)
            lags += [heard[seq] - t for seq, t in on_agent.items() if seq in heard]
            total += len(on_agent)
        lag_p50_s, lag_p95_s = percentile(lags, 0.5), percentile(lags, 0.95)
        if lag_p50_s is None or lag_p95_s is None:
            raise AssertionError(
                f"{robots} robot(s): 0 samples heard of {total} on the agents\n"
                + "\n".join(proc.output(30) for proc in children.values())
            )
        return Round(
            robots=robots,
            samples=total,
            lag_p50_s=lag_p50_s,
            lag_p95_s=lag_p95_s,
            lag_max_s=max(lags),
            collector_cpu=cpu["collector"],
            worker_cpu=cpu["worker"],
            agents_cpu=sum(cpu[name] for name in pids if name.startswith("agent-")),
            exact=exact,
        )
    finally:
        listener.close()
        for proc in reversed(list(children.values())):
            proc.stop()


def run(
    *,
    database_url: str,
    robots: Sequence[int] = ROBOTS,
    program_s: float = PROGRAM_S,
    redis_url: str | None = None,
) -> tuple[str, list[Round]]:
    """Run one round per count of robots against ``database_url`` (migrated); the report's
    markdown and the rounds."""
    import django

    os.environ.setdefault("DJANGO_SETTINGS_MODULE", "portal.settings")
    django.setup()

    work = Path(tempfile.mkdtemp(prefix="bench-scale-"))
    server = None
    try:
        if redis_url is None:
            server = RedisServer(work / "redis")
            server.start()
            redis_url = f"redis://127.0.0.1:{server.port}"
        token = secrets.token_urlsafe(24)
        env = dict(os.environ)
        env.update(
            {
                "DJANGO_DEBUG": "1",
                "DATABASE_URL": database_url,
                "REDIS_URL": f"{redis_url}/0",
                "CELERY_BROKER_URL": f"{redis_url}/1",
                "AGENT_TOKEN": token,
                "AMAZING_VAR_DIR": str(work / "var"),
                "PYTHONUNBUFFERED": "1",
                "LOG_LEVEL": "WARNING",
            }
        )
        for key in ("AGENT_TOKEN_FILE", "AGENT_TOKENS", "AGENT_TOKENS_FILE"):
            env.pop(key, None)
        rounds = [
            _round(
                robots=n,
                program_s=program_s,
                env=env,
                redis_url=f"{redis_url}/0",
                work=work,
                token=token,
            )
            for n in robots
        ]
    finally:
        if server is not None:
            server.stop()
        shutil.rmtree(work, ignore_errors=True)
    report = "\n".join(
        [
            "## Many robots: collection lag and CPU",
            "",
            f"N agents, each with its simulated robot, each running a {program_s:g} s program "
            f"at {HZ:g} Hz, all starting at once; one Celery worker (runs queue), the "
            "collector, beat sweeping every 2 s, PostgreSQL, Redis. Lag = when the "
            "`samples` event announcing a sample was heard (published right after the commit "
            "that stored it) minus the sample's `t`. CPU = user + system time over the "
            "programs' length as a share of one core (per robot in brackets).",
            "",
            "| robots | samples | lag p50 | lag p95 | lag max | collector CPU (per robot) "
            "| worker CPU (per robot) | agent CPU per robot | each stored and announced once |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
            *(r.row() for r in rounds),
            "",
            f"Target: 8 robots with one worker, lag p95 ≤ {LAG_TARGET_S * 1000:.0f} ms.",
        ]
    )
    return report, rounds
