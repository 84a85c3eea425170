"""``make soak``: the whole system for ``SOAK_MINUTES`` under random faults, then checked.

Everything runs as in production (``portal.processes``, through ``bench/stack.py``): a
private PostgreSQL cluster (``initdb`` in a scratch directory, on a free port, so that it can
be restarted without disturbing the machine's server), a private redis-server (broker, cache,
live bus), the stand-in testbed scheduler, two agents each with its simulated robot, both
Celery workers (runs and mail), beat, the web server, the streams server and the collector.

- **Driver**: for each robot a client books runs back to back through the public API (the
  ``amazing`` command's client), about one in three holding a fixed node too (a lease on the
  stand-in). Each booking has its own ``X-Idempotency-Key`` and is retried with it while the
  portal does not answer, answers 5xx, or is still handling the same key.
- **Chaos**: every 60 to 180 s (seeded), one of the runs worker, the mail worker, beat, Redis,
  an agent, the web server or the stand-in is killed with SIGKILL, and PostgreSQL is
  restarted once (an immediate shutdown: a crash, recovered at the start). Whatever died is
  started again as the launcher would (``portal.launcher``'s pauses).
- **Operator**: a robot the health check takes out of booking is put back in service (as an
  admin would, audited) when a fault injected on its agent explains the hold; any other hold
  stays, and fails the soak.
- **Checks** at the end, each a list of misses (:data:`CHECKS`): every run in an end state;
  each run holds exactly its agent's samples (sequence, time and values); each interrupted
  run's missing ranges equal the agent's gaps; no sample stored twice; no idempotency key
  booked twice; no lease on the stand-in without its booking, no booking without its lease;
  no task left in the broker; every hold lifted or explained.

``python -m bench.soak --minutes 30`` writes the report (markdown, JSON, and a plot of runs
over time with the faults marked) into ``--out``; ``--report`` also puts it into
docs/reliability.md. The exit code is 1 when a check found a miss.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import redis
import requests

from amazing_cli.api import Api
from amazing_cli.errors import CliError
from basestation.client import AgentClient, AgentError
from bench.stack import REPO, PostgresCluster, RedisServer, Stack, running_stack

DEFAULT_MINUTES = 30.0
CHAOS_EVERY_S = (60.0, 180.0)
PROGRAM_S = 30.0
# A reservation lasts its program and this much more (the run's collection ends inside it).
SLACK_S = 4.0
# From a booking to its start: staged by the next sweeps.
LEAD_S = 8.0
FIXED_NODE_SHARE = 1 / 3
VELOCITY_MPS = 0.5
# A booking that gets no answer is retried with its key for this long at most.
RETRY_FOR_S = 180.0
# A hold counts as explained by a fault on the robot's agent this long before it.
HOLD_EXPLAINED_WITHIN_S = 300.0
DATABASE = "amazing_soak"
REPORT = REPO / "docs" / "reliability.md"
PLOT = REPO / "docs" / "reliability-soak.png"

# Robot, its agent's process, and the fixed nodes its bookings may hold (the two robots'
# nodes apart: a refusal for a node the other robot's booking holds would only be noise).
ROBOTS = {
    "mobile-1": ("agent", ("node-01", "node-03", "node-05")),
    "mobile-2": ("agent-2", ("node-02", "node-04", "node-06")),
}
# Fault kinds: the process killed (by its name in ``portal.processes``), in words.
KILLED = {
    "worker": "runs worker",
    "mail": "mail worker",
    "beat": "beat",
    "redis": "Redis",
    "agent": "agent",
    "web": "web server",
    "scheduler": "stand-in scheduler",
}
POSTGRES_RESTART = "postgresql"
# Each Celery queue and the worker process that takes its tasks (portal.processes).
QUEUE_WORKERS = {"runs": "worker", "mail": "mail"}
FAULT_NAMES = {**KILLED, POSTGRES_RESTART: "PostgreSQL restart"}
END_STATES = ("completed", "interrupted", "failed", "cancelled")
CHECKS = {
    "runs_ended": "every run in an end state",
    "samples_exact": "each run holds exactly its agent's samples",
    "missing_equals_gaps": "each interrupted run's missing ranges equal the agent's gaps",
    "no_duplicates": "no sample stored twice",
    "keys_once": "no idempotency key booked twice",
    "leases_match": "no lease without its booking, no booking without its lease",
    "no_task_stuck": "no task left in the broker",
    "holds_explained": "every robot hold lifted or explained",
}


def say(line: str) -> None:
    print(f"soak {datetime.now(UTC):%H:%M:%S} {line}", flush=True)


@dataclass
class Fault:
    kind: str
    at_s: float  # since the soak's start
    target: str  # the process killed (which agent), or the server restarted


@dataclass
class Booking:
    robot: str
    key: str
    start_at: str
    end_at: str
    nodes: list[str]
    attempts: int = 0
    errors: list[str] = field(default_factory=list)
    reservation_id: int | None = None
    run_id: int | None = None
    refused: str = ""


@dataclass
class RunRecord:
    id: int
    robot: str
    nodes: list[str]
    start_s: float
    end_s: float
    state: str
    samples: int
    agent_samples: int
    reason: str


@dataclass
class SoakResult:
    minutes: float
    seed: int
    started_at: str
    machine: str
    faults: list[Fault]
    restarts: list[tuple[str, float]]
    bookings: list[Booking]
    runs: list[RunRecord]
    holds: list[dict[str, Any]]
    misses: dict[str, list[str]]
    samples_stored: int = 0
    samples_on_agents: int = 0
    leases: int = 0
    # Leases on the scheduler holding nodes for no booking; bookings whose lease does not.
    orphan_leases: int = 0
    bookings_without_lease: int = 0
    # Tasks a killed worker had taken: Redis hands them out again after its visibility timeout.
    awaiting_redelivery: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not any(self.misses.values())

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["ok"] = self.ok
        return data


class _Supervisor:
    """Starts again whatever died, after the launcher's pause (``portal.launcher.Child``)."""

    def __init__(self, soak: Soak) -> None:
        from portal.launcher import Child

        self.soak = soak
        self.children = {name: Child(name, []) for name in [*soak.stack.specs, "redis"]}
        self.due: dict[str, float] = {}

    def look(self) -> None:
        now = time.monotonic()
        stack, server = self.soak.stack, self.soak.redis
        for name, child in self.children.items():
            with self.soak.lock:
                alive = server.alive if name == "redis" else stack.procs[name].alive
                if alive:
                    continue
                if name not in self.due:
                    pause_s = child.died(now)
                    if pause_s is None:
                        self.soak.miss("no_task_stuck", f"{name} died too often to be restarted")
                        pause_s = 30.0
                    self.due[name] = now + pause_s
                    continue
                if now < self.due[name]:
                    continue
                del self.due[name]
                if name == "redis":
                    server.start()
                else:
                    stack.start(name)
            self.soak.restarts.append((name, self.soak.elapsed_s()))
            say(f"{name} started again")


class Soak:
    def __init__(
        self,
        *,
        work: Path,
        minutes: float,
        seed: int,
        chaos_every_s: tuple[float, float],
        program_s: float,
        until_each_fault: bool = False,
    ) -> None:
        self.work = work
        self.minutes = minutes
        self.until_each_fault = until_each_fault
        # When booking stops (epoch seconds): ``minutes`` after the start, or sooner with
        # ``until_each_fault``.
        self.window_end = 0.0
        self.seed = seed
        self.chaos_every_s = chaos_every_s
        self.program_s = program_s
        self.rng = random.Random(seed)
        self.lock = threading.RLock()
        self.stopping = threading.Event()
        self.faults: list[Fault] = []
        self.restarts: list[tuple[str, float]] = []
        self.bookings: list[Booking] = []
        self.holds: list[dict[str, Any]] = []
        self.awaiting_redelivery: list[str] = []
        self.misses: dict[str, list[str]] = {key: [] for key in CHECKS}
        self.started_mono = 0.0
        self.started_epoch_s = 0.0
        self.started_at = datetime.now(UTC)
        self.postgres = PostgresCluster()
        self.redis = RedisServer(work / "redis")
        self.stack: Stack
        self.tokens: dict[str, str] = {}

    def elapsed_s(self) -> float:
        return round(time.monotonic() - self.started_mono, 1)

    def miss(self, check: str, what: str) -> None:
        with self.lock:
            self.misses[check].append(what)
        say(f"MISS ({CHECKS[check]}): {what}")

    # -- the system ------------------------------------------------------------------------

    @property
    def database_url(self) -> str:
        return self.postgres.url(DATABASE)

    def _migrate(self) -> None:
        env = {**os.environ, "DJANGO_DEBUG": "1", "DATABASE_URL": self.database_url}
        subprocess.run(
            [sys.executable, "manage.py", "migrate", "--no-input", "-v", "0"],
            cwd=REPO,
            env=env,
            check=True,
        )

    @staticmethod
    def _environment() -> dict[str, str]:
        # The production defaults, not the fast sweeps of the integration tests.
        return {
            "RUN_SWEEP_INTERVAL_S": "2",
            "SCHEDULER_SYNC_INTERVAL_S": "30",
            "LOG_LEVEL": "INFO",
        }

    def _setup_django(self) -> None:
        for key in (
            "DATABASE_URL",
            "REDIS_URL",
            "CELERY_BROKER_URL",
            "SCHEDULER_URL",
            "AGENT_TOKEN",
            "AGENT_TOKENS",
            "DJANGO_DEBUG",
            "AMAZING_VAR_DIR",
        ):
            if key in self.stack.env:
                os.environ[key] = self.stack.env[key]
        os.environ.setdefault("DJANGO_SETTINGS_MODULE", "portal.settings")
        import django

        django.setup()

    def _testbed(self) -> None:
        """The two robots, the fixed nodes (as the stand-in lists them), an experimenter
        and an admin, each with an API token."""
        from allauth.mfa.totp.internal.auth import TOTP, generate_totp_secret
        from django.core.management import call_command

        from bookings.models import Resource
        from core.accounts.models import ApiToken, User

        call_command(
            "testbed_setup", agent_url=self.stack.agent_url, verbosity=0, stdout=io.StringIO()
        )
        Resource.objects.update_or_create(
            name="mobile-2",
            defaults={
                "kind": "mobile",
                "agent_url": self.stack.agent2_url,
                "agent_token_name": "mobile-2",
                "max_velocity_mps": 2.0,
                "max_accel_mps2": 1.0,
            },
        )
        experimenter = User.objects.create_user("soak", email="soak@example.org", password=None)
        admin = User.objects.create_user(
            "soak-admin", email="soak-admin@example.org", password=None, is_staff=True
        )
        # A staff account's token works only while it has MFA (TOTP, as its page sets up).
        TOTP.activate(admin, generate_totp_secret())
        self.tokens = {
            "experimenter": ApiToken.objects.create(user=experimenter, name="bench")[1],
            "admin": ApiToken.objects.create(user=admin, name="soak")[1],
        }

    @property
    def agents(self) -> dict[str, AgentClient]:
        assert self.stack.agent is not None
        assert self.stack.agent2 is not None
        return {"mobile-1": self.stack.agent, "mobile-2": self.stack.agent2}

    # -- the driver ------------------------------------------------------------------------

    def _api(self, who: str) -> Api:
        return Api(self.stack.web, self.tokens[who])

    def _experiment(self, api: Api, robot: str) -> int:
        half = self.program_s / 2
        body = {
            "title": f"soak on {robot}",
            "segments": [
                {"velocity_mps": VELOCITY_MPS, "direction": "cw", "duration_s": half},
                {"velocity_mps": VELOCITY_MPS, "direction": "ccw", "duration_s": half},
            ],
        }
        key = f"soak-experiment-{robot}"
        while True:
            try:
                return int(api.create("experiment_create", body, key=key)["id"])
            except CliError as exc:
                if exc.status is not None and exc.status < 500:
                    raise
                time.sleep(1)

    def _drive(self, robot: str) -> None:
        api = self._api("experimenter")
        experiment = self._experiment(api, robot)
        rng = random.Random(f"{self.seed}-{robot}")
        _, nodes = ROBOTS[robot]
        next_start = time.time() + LEAD_S
        n = 0
        while not self.stopping.is_set():
            start_s = max(next_start, time.time() + LEAD_S)
            if start_s >= self.window_end:
                return
            n += 1
            start = datetime.fromtimestamp(round(start_s), UTC)
            end = start + timedelta(seconds=self.program_s + SLACK_S)
            held = [rng.choice(nodes)] if rng.random() < FIXED_NODE_SHARE else []
            booking = Booking(
                robot=robot,
                key=f"soak-{self.seed}-{robot}-{n}",
                start_at=start.isoformat(),
                end_at=end.isoformat(),
                nodes=held,
            )
            with self.lock:
                self.bookings.append(booking)
            body = {
                "resources": [robot, *held],
                "experiment": experiment,
                "start_at": booking.start_at,
                "end_at": booking.end_at,
            }
            if self._book(api, booking, body):
                next_start = end.timestamp()
                # The next is booked once this one has started: back to back, one ahead.
                self.stopping.wait(max(0.0, start.timestamp() - time.time()))
            else:
                self.stopping.wait(2.0)

    def _book(self, api: Api, booking: Booking, body: dict[str, Any]) -> bool:
        """Book with the booking's key, retrying while no answer settles it."""
        give_up = time.monotonic() + RETRY_FOR_S
        while True:
            booking.attempts += 1
            try:
                answer = api.create("reservation_create", body, key=booking.key)
            except CliError as exc:
                in_flight = exc.status == 409 and "still being handled" in exc.message
                retry = exc.status is None or exc.status >= 500 or in_flight
                booking.errors.append(f"{exc.status or 'no answer'}: {exc.message[:120]}")
                if retry and time.monotonic() < give_up and not self.stopping.is_set():
                    time.sleep(min(5.0, 0.5 * booking.attempts))
                    continue
                booking.refused = exc.message
                say(f"{booking.robot}: booking {booking.key} refused: {exc.message}")
                if "out of service" in exc.message:
                    self._operator_look()
                return False
            booking.reservation_id = int(answer["id"])
            booking.run_id = int(answer["run"]["id"]) if answer.get("run") else None
            say(
                f"{booking.robot}: run {booking.run_id} booked for {booking.start_at[11:19]}"
                + (f" with {', '.join(booking.nodes)}" if booking.nodes else "")
                + (f" after {booking.attempts} attempts" if booking.attempts > 1 else "")
            )
            return True

    # -- the operator ----------------------------------------------------------------------

    def _operator_look(self) -> None:
        """Put back in service a robot whose hold a fault on its agent explains."""
        api = self._api("admin")
        try:
            listed = api.call("resources")
        except CliError:
            return
        resources = listed["results"] if isinstance(listed, dict) else listed
        for resource in resources:
            reason = resource.get("hold_reason") or ""
            robot = resource["name"]
            if not reason or robot not in ROBOTS:
                continue
            with self.lock:
                if any(
                    h["robot"] == robot and h["reason"] == reason and h["open"] for h in self.holds
                ):
                    continue
                cause = self._explaining_fault(robot)
                hold = {
                    "robot": robot,
                    "reason": reason,
                    "at_s": self.elapsed_s(),
                    "explained_by": asdict(cause) if cause else None,
                    "open": True,
                }
                self.holds.append(hold)
            say(f"{robot} held: {reason}")
            if cause is None:
                continue
            why = (
                f"soak: the hold follows the {FAULT_NAMES[cause.kind]} killed at {cause.at_s:.0f} s"
            )
            try:
                # As an admin on the robot's console: back in service, audited with the reason.
                answer = api.session.post(
                    f"{api.url}/api/v1/resources/{robot}/service/",
                    json={"enabled": True, "reason": why},
                    timeout=10,
                )
                answer.raise_for_status()
            except requests.RequestException as exc:  # the next look tries again
                say(f"{robot}: hold not lifted yet: {exc}")
                with self.lock:
                    self.holds.remove(hold)
                continue
            hold["open"] = False
            say(f"{robot} put back in service")

    def _explaining_fault(self, robot: str) -> Fault | None:
        agent, _ = ROBOTS[robot]
        now = self.elapsed_s()
        for fault in reversed(self.faults):
            if fault.target == agent and now - fault.at_s <= HOLD_EXPLAINED_WITHIN_S:
                return fault
        return None

    def _operate(self) -> None:
        while not self.stopping.wait(5.0):
            self._operator_look()

    # -- chaos -----------------------------------------------------------------------------

    def _deck(self, first: bool) -> list[str]:
        """The next kinds in a random order: each occurs once a deck; PostgreSQL is
        restarted once, somewhere in the first."""
        deck = list(KILLED)
        self.rng.shuffle(deck)
        if first:
            deck.insert(self.rng.randrange(len(deck) + 1), POSTGRES_RESTART)
        return deck

    def _chaos(self) -> None:
        deck = self._deck(first=True)
        while True:
            pause_s = self.rng.uniform(*self.chaos_every_s)
            if self.stopping.wait(pause_s) or time.time() + 5 >= self.window_end:
                return
            if not deck:
                if self.until_each_fault:
                    # Every kind has occurred, and runs went on through one more pause
                    # after the last: what the soak is for has been seen.
                    self._close_window()
                    return
                deck = self._deck(first=False)
            self._inject(deck.pop(0))

    def _close_window(self) -> None:
        self.window_end = time.time()
        self.minutes = round((self.window_end - self.started_epoch_s) / 60, 1)
        say(f"every kind of fault has occurred: no more bookings after {self.minutes:g} min")

    def _inject(self, kind: str) -> None:
        at_s = self.elapsed_s()
        if kind == POSTGRES_RESTART:
            target = "postgresql"
            say("PostgreSQL: immediate shutdown, then start")
            self.postgres.stop("immediate")
            self.postgres.start()
        elif kind == "redis":
            target = "redis"
            with self.lock:
                self.redis.stop(sig=9)
        else:
            target = self.rng.choice(["agent", "agent-2"]) if kind == "agent" else kind
            with self.lock:
                self.stack.kill(target)
        self.faults.append(Fault(kind=kind, at_s=at_s, target=target))
        say(f"fault at {at_s:.0f} s: {FAULT_NAMES[kind]} ({target}) killed")

    # -- the whole soak --------------------------------------------------------------------

    def run(self) -> SoakResult:
        self.postgres.init()
        self.postgres.start()
        try:
            self.postgres.create_database(DATABASE)
            self._migrate()
            self.redis.start()
            try:
                with running_stack(
                    self.work / "var",
                    database_url=self.database_url,
                    broker_url=self.redis.url(1),
                    redis_url=self.redis.url(0),
                    second_robot=True,
                    with_scheduler=True,
                    extra_env=self._environment(),
                    log_dir=self.work / "logs",
                    access_log=False,
                ) as stack:
                    self.stack = stack
                    stack.redis = self.redis
                    return self._soak()
            finally:
                self.redis.stop()
        finally:
            from django.db import connections

            connections.close_all()
            self.postgres.stop("fast")
            (self.work / "logs").mkdir(parents=True, exist_ok=True)
            shutil.copy(self.postgres.log, self.work / "logs" / "postgres.log")
            self.postgres.remove()

    def _soak(self) -> SoakResult:
        self._setup_django()
        self._testbed()
        say(f"system up in {self.work}; soaking {self.minutes:g} min, seed {self.seed}")
        self.started_mono = time.monotonic()
        self.started_at = datetime.now(UTC)
        self.started_epoch_s = time.time()
        self.window_end = self.started_epoch_s + self.minutes * 60
        supervisor = _Supervisor(self)

        def watching() -> None:
            while not self.stopping.wait(0.5):
                supervisor.look()

        threads = [
            threading.Thread(target=watching, name="supervisor"),
            threading.Thread(target=self._chaos, name="chaos"),
            threading.Thread(target=self._operate, name="operator"),
            *(threading.Thread(target=self._drive, args=(robot,), name=robot) for robot in ROBOTS),
        ]
        for thread in threads:
            thread.start()
        try:
            drivers = [t for t in threads if t.name in ROBOTS]
            for thread in drivers:
                thread.join()
            # Chaos ends with the window; a process it killed last is started again.
            chaos = next(t for t in threads if t.name == "chaos")
            chaos.join(timeout=self.chaos_every_s[1] + 60)
            time.sleep(5.0)
            supervisor.look()
            self._settle()
        finally:
            self.stopping.set()
            for thread in threads:
                thread.join(timeout=60)
        return self._check()

    def _settle(self) -> None:
        """Wait for every booked run to end (the last ones still run, or are collected)."""
        from django.db import connections

        from portal.runs.models import Run

        run_ids = [b.run_id for b in self.bookings if b.run_id is not None]
        deadline = time.monotonic() + self.program_s + SLACK_S + LEAD_S + 240
        while time.monotonic() < deadline:
            self.stopping.wait(2.0)
            try:
                open_runs = Run.objects.filter(pk__in=run_ids).exclude(state__in=END_STATES)
                if not open_runs.exists():
                    return
            except Exception:  # PostgreSQL restarting: look again
                connections.close_all()
            self._operator_look()

    # -- the checks ------------------------------------------------------------------------

    def _check(self) -> SoakResult:
        from django.db import connections

        connections.close_all()
        runs = self._check_runs()
        self._check_duplicates()
        self._check_keys()
        leases, orphans, unheld = self._check_leases()
        self._check_tasks()
        self._check_holds()
        return SoakResult(
            minutes=self.minutes,
            seed=self.seed,
            started_at=self.started_at.isoformat(timespec="seconds"),
            machine=_machine(),
            faults=self.faults,
            restarts=self.restarts,
            bookings=self.bookings,
            runs=runs,
            holds=self.holds,
            misses=self.misses,
            samples_stored=sum(r.samples for r in runs),
            samples_on_agents=sum(r.agent_samples for r in runs),
            leases=leases,
            orphan_leases=orphans,
            bookings_without_lease=unheld,
            awaiting_redelivery=self.awaiting_redelivery,
        )

    def _check_runs(self) -> list[RunRecord]:
        from portal.runs.models import Run, Sample

        records = []
        booked = {b.run_id: b for b in self.bookings if b.run_id is not None}
        for run in Run.objects.filter(pk__in=list(booked)).select_related("resource"):
            booking = booked[run.pk]
            if run.state not in END_STATES:
                self.miss("runs_ended", f"run {run.pk} is {run.state}")
            agent = self.agents[booking.robot]
            try:
                on_agent = list(agent.iter_samples(f"run-{run.pk}"))
                agent_run: dict[str, Any] | None = agent.get_run(f"run-{run.pk}")
            except AgentError as exc:
                if exc.status != 404:
                    raise
                on_agent, agent_run = [], None
            stored = list(
                Sample.objects.filter(run=run)
                .order_by("seq")
                .values_list("seq", "t", "velocity_mps", "track_m", "battery_v")
            )
            expected = [
                (s["seq"], s["t"], s["velocity_mps"], s["track_m"], s["battery_v"])
                for s in on_agent
            ]
            got = [(seq, t.timestamp(), v, track, battery) for seq, t, v, track, battery in stored]
            if not _same_samples(got, expected):
                lost = sorted({s[0] for s in expected} - {s[0] for s in got})
                extra = sorted({s[0] for s in got} - {s[0] for s in expected})
                self.miss(
                    "samples_exact",
                    f"run {run.pk} ({run.state}): {len(got)} stored, {len(expected)} on the "
                    f"agent; lost {_ranges(lost)}, not on the agent {_ranges(extra)}",
                )
            if run.state == "completed":
                seqs = [s[0] for s in expected]
                if seqs != list(range(1, len(seqs) + 1)) or not seqs:
                    self.miss("samples_exact", f"run {run.pk} completed with gaps on the agent")
            if run.state == "interrupted":
                gaps = _agent_gaps(
                    [s[0] for s in expected],
                    agent_last_seq=int(agent_run["last_seq"] or 0) if agent_run else 0,
                    ended_early=agent_run is None or agent_run["state"] != "completed",
                )
                missing = [(m["first_seq"], m["last_seq"]) for m in run.missing]
                if missing != gaps:
                    self.miss(
                        "missing_equals_gaps",
                        f"run {run.pk}: missing {missing}, the agent's gaps {gaps}",
                    )
            records.append(
                RunRecord(
                    id=run.pk,
                    robot=booking.robot,
                    nodes=booking.nodes,
                    start_s=(run.start_at - self.started_at).total_seconds(),
                    end_s=(run.end_at - self.started_at).total_seconds(),
                    state=run.state,
                    samples=len(got),
                    agent_samples=len(expected),
                    reason=run.reason,
                )
            )
        missing_runs = set(booked) - {r.id for r in records}
        for run_id in sorted(missing_runs):
            self.miss("runs_ended", f"run {run_id} was booked (201) but does not exist")
        return sorted(records, key=lambda r: r.start_s)

    def _check_duplicates(self) -> None:
        from django.db.models import Count

        from portal.runs.models import Sample

        doubled = (
            Sample.objects.values("run_id", "seq")
            .annotate(n=Count("id"))
            .filter(n__gt=1)
            .order_by("run_id", "seq")
        )
        for row in doubled[:20]:
            self.miss("no_duplicates", f"run {row['run_id']} seq {row['seq']} stored {row['n']}×")

    def _check_keys(self) -> None:
        from bookings.models import Reservation
        from core.audit.models import IdempotencyKey

        keys = {
            k.key: k
            for k in IdempotencyKey.objects.filter(
                user__username="soak", path="/api/v1/reservations/"
            )
        }
        by_reservation = Counter(
            int(k.response["id"]) for k in keys.values() if k.status == 201 and k.response
        )
        for reservation_id, n in by_reservation.items():
            if n > 1:
                self.miss("keys_once", f"reservation {reservation_id} answered to {n} keys")
        reservations = set(
            Reservation.objects.filter(owner__username="soak").values_list("pk", flat=True)
        )
        for reservation_id in sorted(reservations - set(by_reservation)):
            self.miss("keys_once", f"reservation {reservation_id} was booked under no key")
        for booking in self.bookings:
            stored = keys.get(booking.key)
            answer = stored.response if stored is not None and stored.status == 201 else None
            held = int(answer["id"]) if isinstance(answer, dict) else None
            if booking.reservation_id is not None and held != booking.reservation_id:
                self.miss(
                    "keys_once",
                    f"{booking.key}: answered reservation {booking.reservation_id}, "
                    f"the key holds {held}",
                )
            elif booking.reservation_id is None and held is not None:
                self.miss(
                    "keys_once",
                    f"{booking.key}: refused to the client ({booking.refused}) yet booked "
                    f"reservation {held}",
                )

    def _check_leases(self) -> tuple[int, int, int]:
        """The portal's leases on the stand-in against its bookings: how many leases, how
        many hold nodes for no booking, how many bookings are not held by theirs."""
        from django.conf import settings

        from bookings.leases import public_id_of, scheduler_client
        from bookings.models import Reservation
        from bookings.scheduler import ALL_STATUSES

        assert settings.SCHEDULER is not None
        with scheduler_client() as scheduler:
            leases = scheduler.list_leases(
                window_start=self.started_at - timedelta(hours=1),
                window_end=datetime.now(UTC) + timedelta(days=1),
                statuses=ALL_STATUSES,
            )
        ours = [lease for lease in leases if public_id_of(lease.name) is not None]
        bookings = {
            str(r.public_id): r
            for r in Reservation.objects.filter(owner__username="soak").exclude(lease_uuid="")
        }
        orphans = unheld = 0
        for lease in ours:
            status = lease.status.value
            booking = bookings.get(str(public_id_of(lease.name)))
            if status == "cancelled":
                continue  # held nothing; a booking it should hold is counted below
            if booking is None or booking.lease_uuid != lease.uuid:
                orphans += 1
                self.miss(
                    "leases_match",
                    f"lease {lease.uuid} ({status}, {', '.join(lease.component_names)}, "
                    f"{lease.valid_from:%H:%M:%S}–{lease.valid_until:%H:%M:%S}) has no booking",
                )
        by_uuid = {lease.uuid: lease for lease in ours}
        for booking in bookings.values():
            own = by_uuid.get(booking.lease_uuid)
            if booking.state in ("cancelled", "rejected"):
                continue
            if own is None or own.status.value in ("cancelled", "pending"):
                unheld += 1
                self.miss(
                    "leases_match",
                    f"reservation {booking.pk} ({booking.state}) has no lease holding its nodes "
                    f"({own.status.value if own else 'none on the scheduler'})",
                )
            elif own.valid_from > booking.start_at or own.valid_until < booking.end_at:
                unheld += 1
                self.miss("leases_match", f"reservation {booking.pk}: its lease does not cover it")
        return len(ours), orphans, unheld

    def _check_tasks(self) -> None:
        """The broker drains: both queues empty at some moment, and no task taken but
        unacknowledged for longer than a task may last — except those a killed worker had
        taken, which Redis hands out again after the visibility timeout (their work is redone
        meanwhile by the sweeps, as the checks of the runs show); those are listed."""
        from django.conf import settings

        client = redis.Redis.from_url(self.redis.url(1))
        longest_task_s = 300.0  # the longest time limit of any task (the daily clean-up)
        visibility_s = float(settings.CELERY_VISIBILITY_TIMEOUT_S)
        deadline = time.monotonic() + 60
        while True:
            queued = {queue: client.llen(queue) for queue in QUEUE_WORKERS}
            now_s = time.time()
            stuck, awaiting = [], []
            for task, queue, taken_s in _unacknowledged(client):
                killed_s = self._last_kill_epoch_s(QUEUE_WORKERS.get(queue, ""))
                held_by_dead = killed_s is not None and taken_s <= killed_s
                age_s = now_s - taken_s
                if held_by_dead and age_s <= visibility_s:
                    awaiting.append(f"{task} ({queue}, taken {age_s:.0f} s ago)")
                elif age_s > (visibility_s if held_by_dead else longest_task_s):
                    stuck.append(f"{task} ({queue}, taken {age_s:.0f} s ago)")
            if not any(queued.values()) and not stuck:
                self.awaiting_redelivery = awaiting
                return
            if time.monotonic() > deadline:
                self.miss("no_task_stuck", f"queued {queued}; unacknowledged: {stuck}")
                self.awaiting_redelivery = awaiting
                return
            time.sleep(1.0)

    def _last_kill_epoch_s(self, process: str) -> float | None:
        kills = [f.at_s for f in self.faults if f.target == process]
        redis_lost = [f.at_s for f in self.faults if f.kind == "redis"]
        # A Redis crash loses what it held, unacknowledged messages with it.
        if not kills or (redis_lost and max(redis_lost) > max(kills)):
            return None
        return self.started_at.timestamp() + max(kills)

    def _check_holds(self) -> None:
        from bookings.models import Resource

        self._operator_look()
        for hold in self.holds:
            if hold["explained_by"] is None:
                self.miss("holds_explained", f"{hold['robot']}: {hold['reason']}")
        for robot in Resource.objects.filter(name__in=list(ROBOTS)).exclude(hold_reason=""):
            if not any(h["robot"] == robot.name for h in self.holds):
                self.miss("holds_explained", f"{robot.name} held: {robot.hold_reason}")


def _unacknowledged(client: redis.Redis) -> list[tuple[str, str, float]]:
    """The messages a worker has taken and not acknowledged (kombu's Redis transport keeps
    them in ``unacked``, indexed by when they were taken): task name, queue, when."""
    taken: list[tuple[bytes, float]] = client.zrange(  # type: ignore[assignment]
        "unacked_index", 0, -1, withscores=True
    )
    found = []
    for tag, taken_s in taken:
        raw = client.hget("unacked", tag)
        if raw is None:
            continue  # acknowledged meanwhile
        message, _exchange, queue = json.loads(raw)
        task = str(message.get("headers", {}).get("task", "?"))
        found.append((task, str(queue), float(taken_s)))
    return found


def _same_samples(got: list[tuple[Any, ...]], expected: list[tuple[Any, ...]]) -> bool:
    if len(got) != len(expected):
        return False
    for a, b in zip(got, expected, strict=True):
        if a[0] != b[0] or abs(a[1] - b[1]) > 1e-6 or a[2:] != b[2:]:
            return False
    return True


def _agent_gaps(
    seqs: list[int], *, agent_last_seq: int, ended_early: bool
) -> list[tuple[int, int | None]]:
    """What the agent lacks, as the portal must report it: the sequence numbers missing
    among its samples, those it spent after its last sample, and — when it stopped before the
    program's end — everything after."""
    gaps: list[tuple[int, int | None]] = []
    previous = 0
    for seq in seqs:
        if seq > previous + 1:
            gaps.append((previous + 1, seq - 1))
        previous = seq
    if agent_last_seq > previous:
        gaps.append((previous + 1, agent_last_seq))
    elif ended_early:
        gaps.append((previous + 1, None))
    return gaps


def _ranges(seqs: Sequence[int]) -> str:
    if not seqs:
        return "none"
    parts, first, last = [], seqs[0], seqs[0]
    for seq in [*seqs[1:], None]:
        if seq is not None and seq == last + 1:
            last = seq
            continue
        parts.append(f"{first}" if first == last else f"{first}–{last}")
        if seq is not None:
            first = last = seq
    return ", ".join(parts[:10]) + (" …" if len(parts) > 10 else "")


def _machine() -> str:
    from bench.__main__ import machine

    return machine()


# -- the report ----------------------------------------------------------------------------


def _clock(seconds: float) -> str:
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


def report_markdown(result: SoakResult, *, plot_name: str | None) -> str:
    states = Counter(r.state for r in result.runs)
    kinds = Counter(f.kind for f in result.faults)
    booked = [b for b in result.bookings if b.reservation_id is not None]
    retried = [b for b in booked if b.attempts > 1]
    refused = [b for b in result.bookings if b.reservation_id is None]
    with_nodes = [r for r in result.runs if r.nodes]
    lost = sum(max(0, r.agent_samples - r.samples) for r in result.runs)
    lines = [
        f"### {result.minutes:g} minutes, seed {result.seed}",
        "",
        f"Started {result.started_at[:16].replace('T', ' ')} UTC on {result.machine}.",
        "",
        "| runs | completed | interrupted | failed | cancelled | with a fixed node |",
        "| --- | --- | --- | --- | --- | --- |",
        f"| {len(result.runs)} | {states['completed']} | {states['interrupted']} "
        f"| {states['failed']} | {states['cancelled']} | {len(with_nodes)} |",
        "",
        "| samples on the agents | stored | lost | duplicated | leases | orphan leases "
        "| bookings without their lease |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        f"| {result.samples_on_agents:,} | {result.samples_stored:,} | {lost} "
        f"| {len(result.misses['no_duplicates'])} | {result.leases} | {result.orphan_leases} "
        f"| {result.bookings_without_lease} |".replace(",", " "),
        "",
        f"Bookings: {len(booked)} made, {len(retried)} of them after retries with their key "
        f"({sum(b.attempts - 1 for b in retried)} retries), {len(refused)} refused"
        + (" (" + "; ".join(sorted({b.refused[:100] for b in refused})) + ")" if refused else "")
        + f". Processes started again after a death: {len(result.restarts)}.",
        "",
        f"Faults injected: {len(result.faults)}.",
        "",
        "| fault | count | at (min:s since the start) |",
        "| --- | --- | --- |",
    ]
    for kind, name in FAULT_NAMES.items():
        times = [f for f in result.faults if f.kind == kind]
        at = ", ".join(
            _clock(f.at_s) + (f" ({f.target})" if f.kind == "agent" else "") for f in times
        )
        lines.append(f"| {name} | {kinds[kind]} | {at or '–'} |")
    lines += ["", "| check | result |", "| --- | --- |"]
    for key, words in CHECKS.items():
        misses = result.misses[key]
        shown = "; ".join(misses[:5]) + (" …" if len(misses) > 5 else "")
        lines.append(f"| {words} | {'ok' if not misses else f'{len(misses)} missed: {shown}'} |")
    if result.awaiting_redelivery:
        lines += [
            "",
            "Tasks a killed worker had taken, which Redis hands out again after its "
            "visibility timeout (their work was redone by the sweeps meanwhile): "
            + "; ".join(result.awaiting_redelivery)
            + ".",
        ]
    interrupted = [r for r in result.runs if r.state in ("interrupted", "failed")]
    if interrupted:
        lines += ["", "Runs not completed:", ""]
        lines += [f"- run {r.id} on {r.robot}, {r.state}: {r.reason}" for r in interrupted]
    if result.holds:
        lines += ["", "Robot holds:", ""]
        for hold in result.holds:
            cause = hold["explained_by"]
            why = (
                f"after the {FAULT_NAMES[cause['kind']]} ({cause['target']}) killed at "
                f"{_clock(cause['at_s'])}; put back in service"
                if cause
                else "unexplained"
            )
            lines.append(f"- {hold['robot']} at {_clock(hold['at_s'])}: {hold['reason']} — {why}")
    if plot_name:
        lines += ["", f"![Runs over time, faults marked]({plot_name})"]
    return "\n".join(lines)


STATE_COLOURS = {
    "completed": "#2e7d32",
    "interrupted": "#ef6c00",
    "failed": "#c62828",
    "cancelled": "#757575",
}


def plot(result: SoakResult, path: Path) -> None:
    """Runs over time, one lane per robot (hatched: with a fixed node), coloured by how they
    ended; the faults as vertical lines, one colour per kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.artist import Artist
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    fig, ax = plt.subplots(figsize=(12, 3.6), dpi=100)
    lanes = {robot: i for i, robot in enumerate(ROBOTS)}
    for run in result.runs:
        ax.barh(
            lanes[run.robot],
            (run.end_s - run.start_s) / 60,
            left=run.start_s / 60,
            height=0.6,
            color=STATE_COLOURS.get(run.state, "#9e9e9e"),
            edgecolor="white",
            linewidth=0.5,
            hatch="//" if run.nodes else None,
        )
    palette = plt.get_cmap("tab10")
    kind_colour = {kind: palette(i) for i, kind in enumerate(FAULT_NAMES)}
    for fault in result.faults:
        ax.axvline(fault.at_s / 60, color=kind_colour[fault.kind], linewidth=1.6, alpha=0.9)
    ax.set_yticks(list(lanes.values()), list(lanes))
    ax.set_ylim(-0.7, len(lanes) - 0.3)
    ax.set_xlabel("minutes since the start")
    ax.set_title(
        f"Soak: {len(result.runs)} runs, {len(result.faults)} faults "
        f"({result.minutes:g} min, seed {result.seed})"
    )
    handles: list[Artist] = [Patch(color=c, label=s) for s, c in STATE_COLOURS.items()]
    handles.append(Patch(facecolor="white", edgecolor="black", hatch="//", label="fixed node"))
    kinds_seen = {f.kind for f in result.faults}
    handles += [
        Line2D([0], [0], color=kind_colour[k], label=FAULT_NAMES[k])
        for k in FAULT_NAMES
        if k in kinds_seen
    ]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_report(markdown: str) -> None:
    """Replace (or add) the soak's section of docs/reliability.md, between its markers."""
    begin, end = "<!-- soak -->", "<!-- /soak -->"
    text = REPORT.read_text() if REPORT.exists() else "# Reliability\n"
    block = f"{begin}\n{markdown.rstrip()}\n{end}"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    REPORT.write_text(text)


def run(
    *,
    minutes: float = DEFAULT_MINUTES,
    seed: int = 1,
    chaos_every_s: tuple[float, float] = CHAOS_EVERY_S,
    program_s: float = PROGRAM_S,
    work: Path | None = None,
    until_each_fault: bool = False,
) -> SoakResult:
    """One soak in ``work`` (a scratch directory by default, removed when it passes)."""
    scratch = work is None
    work = work or Path(tempfile.mkdtemp(prefix="soak-"))
    result = Soak(
        work=work,
        minutes=minutes,
        seed=seed,
        chaos_every_s=chaos_every_s,
        program_s=program_s,
        until_each_fault=until_each_fault,
    ).run()
    if scratch and result.ok:
        shutil.rmtree(work, ignore_errors=True)
    elif not result.ok:
        say(f"the processes' logs are in {work / 'logs'}")
    return result


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.soak", description=__doc__)
    parser.add_argument(
        "--minutes",
        type=float,
        default=float(os.environ.get("SOAK_MINUTES") or DEFAULT_MINUTES),
        help="how long runs are booked and faults injected (SOAK_MINUTES; default 30)",
    )
    parser.add_argument("--seed", type=int, default=int(os.environ.get("SOAK_SEED") or 1))
    parser.add_argument(
        "--chaos-every-s",
        nargs=2,
        type=float,
        default=list(CHAOS_EVERY_S),
        metavar=("MIN", "MAX"),
        help="pause between faults, drawn between these (default 60 180)",
    )
    parser.add_argument("--program-s", type=float, default=PROGRAM_S, help="each run's program")
    parser.add_argument(
        "--until-each-fault",
        action="store_true",
        help="stop booking one pause after every kind of fault has occurred once "
        "(at most --minutes)",
    )
    parser.add_argument("--out", type=Path, help="write soak.md, soak.json and soak.png here")
    parser.add_argument(
        "--report", action="store_true", help="also write the report into docs/reliability.md"
    )
    parser.add_argument("--work", type=Path, help="keep the servers' data and logs here")
    args = parser.parse_args(argv)
    low, high = args.chaos_every_s
    if not 0 < low <= high:
        parser.error("--chaos-every-s: 0 < MIN <= MAX")
    result = run(
        minutes=args.minutes,
        seed=args.seed,
        chaos_every_s=(low, high),
        program_s=args.program_s,
        work=args.work,
        until_each_fault=args.until_each_fault,
    )
    plots: list[tuple[Path, str]] = []
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "soak.json").write_text(json.dumps(result.to_json(), indent=1))
        plots.append((args.out / "soak.png", "soak.png"))
        plot(result, args.out / "soak.png")
        (args.out / "soak.md").write_text(report_markdown(result, plot_name="soak.png"))
    if args.report:
        plot(result, PLOT)
        write_report(report_markdown(result, plot_name=PLOT.name))
        say(f"written to {REPORT.relative_to(REPO)}")
    print(report_markdown(result, plot_name=None))
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
