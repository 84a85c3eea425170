"""The soak's system and what acts on it: the drivers booking runs, the operator, the chaos."""

from __future__ import annotations

import io
import os
import random
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import asdict
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import requests

from amazing_cli.api import Api
from amazing_cli.errors import CliError
from basestation.client import AgentClient
from bench.soak.checks import check
from bench.soak.model import (
    CHECKS,
    DATABASE,
    END_STATES,
    FAULT_NAMES,
    FIXED_NODE_SHARE,
    HOLD_EXPLAINED_WITHIN_S,
    KILLED,
    LEAD_S,
    POSTGRES_RESTART,
    RETRY_FOR_S,
    ROBOTS,
    SLACK_S,
    VELOCITY_MPS,
    Booking,
    Fault,
    SoakResult,
    say,
)
from bench.stack import REPO, PostgresCluster, RedisServer, Stack, running_stack


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
        return check(self)

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
