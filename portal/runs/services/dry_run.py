"""Dry runs: a program tried on a simulated robot of its own, before a booking is spent on it.

A dry run is asked for (``dry_run_request``), waits in line for one of ``DRY_RUN_SLOTS``
places (``dry_run_place`` says where it stands), and is run by a worker
(``dry_run_execute``) in a short-lived process of its own, ``python -m basestation.dryrun``:
the base station's own run manager driving the kinematic model in simulated time. That
process is given the program, the limits and a rail length, on standard input, and an
environment with nothing of the portal's in it: no resource, no base-station address, no
token. Nothing here can reach a robot (the import contract in pyproject.toml and
``tests/runs/test_dry_run.py`` hold it to that).
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from datetime import timedelta
from typing import Any, Final

from django.conf import settings
from django.db import IntegrityError, transaction
from django.db.models import Q
from django.utils import timezone

from basestation.contract import MAX_SEGMENTS
from bookings.models import Resource
from bookings.rules import FIRST_SEGMENT, velocity_limit, velocity_problem
from bookings.selectors import mobiles_bookable
from core.accounts.models import User
from core.errors import InvalidInput
from portal.experiments.models import Experiment
from portal.runs.models import DryRun
from portal.runs.selectors import robots_for_programs

logger = logging.getLogger(__name__)

# The acceleration when no robot states one: the agent's own default (basestation/config.py).
# Velocity has no such default: it is booking's rule (``bookings.rules.velocity_limit``).
DEFAULT_MAX_ACCEL_MPS2: Final = 1.0
# The rail when no robot has measured one yet: the default rail's length.
DEFAULT_RAIL_LENGTH_M: Final = 120.0
# The simulator's process: it starts in about a second and runs an hour's program in seconds.
PROCESS_TIMEOUT_S: Final = 120.0
WAITING: Final = (DryRun.State.QUEUED, DryRun.State.RUNNING)


def _strictest(values: list[float | None], default: float) -> float:
    known = [v for v in values if v is not None]
    return min(known) if known else default


def _slowest_robot() -> tuple[Resource, float]:
    """The bookable robot with the lowest velocity limit as booking computes it, and that
    limit: a program it takes, every robot takes."""
    limited = [
        (robot, limit.mps) for robot in mobiles_bookable() if (limit := velocity_limit(robot))
    ]
    if not limited:
        raise InvalidInput(
            "No robot can be booked now, so there are no limits to try the program under."
        )
    return min(limited, key=lambda pair: pair[1])


def dry_run_request(*, user: User, experiment: Experiment) -> DryRun:
    """Queue a dry run of ``experiment``'s program under the strictest limits of the robots
    ``user`` may book; the caller queues ``dry_run_execute`` after the commit."""
    if experiment.owner_id != user.pk:
        raise InvalidInput.on_field("experiment", "You can try only your own experiments.")
    segments = list(experiment.segments)
    if not segments:
        raise InvalidInput.on_field("segments", "The program has no segments to try.")
    if len(segments) > MAX_SEGMENTS:
        raise InvalidInput.on_field("segments", f"A program has at most {MAX_SEGMENTS} segments.")
    slowest, velocity = _slowest_robot()
    for number, segment in enumerate(segments, FIRST_SEGMENT):
        problem = velocity_problem(resource=slowest, velocity_mps=float(segment["velocity_mps"]))
        if problem:
            raise InvalidInput.on_field(
                "segments",
                f"Segment {number}: {problem} Booking would refuse it, so the simulator does too.",
            )
    robots = robots_for_programs()
    accel = _strictest([r["max_accel_mps2"] for r in robots], DEFAULT_MAX_ACCEL_MPS2)
    rail_m = next((r["rail_length_m"] for r in robots if r["rail_length_m"]), DEFAULT_RAIL_LENGTH_M)
    with transaction.atomic():
        # One person's waiting dry runs, counted under a lock on that person's row.
        User.objects.select_for_update().filter(pk=user.pk).first()
        waiting = DryRun.objects.filter(owner=user, state__in=WAITING).count()
        if waiting >= settings.DRY_RUN_MAX_WAITING:
            raise InvalidInput(
                f"You have {waiting} dry runs waiting or running; try again when one has ended."
            )
        return DryRun.objects.create(
            owner=user,
            experiment=experiment,
            title=experiment.title,
            segments=segments,
            limits={"max_velocity_mps": velocity, "max_accel_mps2": accel},
            rail_length_m=rail_m,
        )


def dry_run_place(dry_run: DryRun) -> int | None:
    """Where a queued dry run stands in line (1: next to run); ``None`` once it runs."""
    if dry_run.state != DryRun.State.QUEUED:
        return None
    ahead = DryRun.objects.filter(state=DryRun.State.QUEUED, pk__lt=dry_run.pk).count()
    return ahead + 1


def _release_lost(now: Any) -> None:
    """Dry runs marked running for longer than any could take lost their worker: failed."""
    lost = DryRun.objects.filter(
        state=DryRun.State.RUNNING,
        started_at__lt=now - timedelta(seconds=settings.DRY_RUN_STALE_S),
    )
    for dry_run in lost:
        logger.warning("dry run %s: its worker stopped while it ran; marked failed", dry_run.pk)
    lost.update(
        state=DryRun.State.FAILED,
        slot=None,
        ended_at=now,
        reason="The simulator stopped before the dry run ended; try again.",
    )


def dry_run_claim(dry_run_id: int) -> DryRun | None:
    """Give the dry run a free place if it is next in line; ``None`` if it must wait (or has
    been run already). First come, first served: the queued dry runs are claimed in order."""
    now = timezone.now()
    with transaction.atomic():
        _release_lost(now)
        # Every waiting dry run locked: two workers claiming at once take turns here, and the
        # unique place per running dry run is the database's guarantee behind it.
        waiting = list(DryRun.objects.select_for_update().filter(state__in=WAITING).order_by("pk"))
        mine = next((d for d in waiting if d.pk == dry_run_id), None)
        if mine is None or mine.state != DryRun.State.QUEUED:
            return None
        taken = {d.slot for d in waiting if d.state == DryRun.State.RUNNING}
        free = [slot for slot in range(settings.DRY_RUN_SLOTS) if slot not in taken]
        queued = [d.pk for d in waiting if d.state == DryRun.State.QUEUED]
        if queued.index(mine.pk) >= len(free):
            return None
        mine.state, mine.slot, mine.started_at = DryRun.State.RUNNING, free[0], now
        try:
            with transaction.atomic():
                mine.save(update_fields=["state", "slot", "started_at"])
        except IntegrityError:
            return None
    return mine


def _simulate(dry_run: DryRun) -> dict[str, Any]:
    """Run the program in the simulator's own process; its answer (basestation/dryrun.py)."""
    request = {
        "segments": dry_run.segments,
        "limits": dry_run.limits,
        "rail_length_m": dry_run.rail_length_m,
    }
    # Nothing of this process's environment: no address, token or setting of the portal's.
    environment = {"PATH": os.environ.get("PATH", ""), "LANG": "C.UTF-8"}
    done = subprocess.run(
        [sys.executable, "-m", "basestation.dryrun"],
        input=json.dumps(request),
        capture_output=True,
        text=True,
        timeout=PROCESS_TIMEOUT_S,
        env=environment,
        check=False,
    )
    try:
        answer: dict[str, Any] = json.loads(done.stdout)
    except ValueError:
        tail = done.stderr.strip().splitlines()[-1:] or [f"exit status {done.returncode}"]
        return {"state": "failed", "reason": f"The simulator failed: {tail[0]}", "samples": []}
    return answer


def dry_run_execute(dry_run_id: int) -> bool:
    """Run the dry run if it is its turn; ``False`` if it must wait for a place."""
    dry_run = dry_run_claim(dry_run_id)
    if dry_run is None:
        return not DryRun.objects.filter(pk=dry_run_id, state=DryRun.State.QUEUED).exists()
    try:
        answer = _simulate(dry_run)
    except subprocess.TimeoutExpired:
        answer = {"state": "failed", "reason": "The simulator took too long.", "samples": []}
    completed = answer.get("state") == "completed" and bool(answer.get("samples"))
    DryRun.objects.filter(pk=dry_run.pk, state=DryRun.State.RUNNING).update(
        state=DryRun.State.COMPLETED if completed else DryRun.State.FAILED,
        slot=None,
        ended_at=timezone.now(),
        samples=answer.get("samples") or [],
        reason="" if completed else str(answer.get("reason") or "The simulator gave no data."),
    )
    logger.info("dry run %s: %s", dry_run.pk, "completed" if completed else answer.get("reason"))
    return True


def dry_runs_next() -> list[int]:
    """The queued dry runs that can take a place now, oldest first."""
    running = DryRun.objects.filter(state=DryRun.State.RUNNING).count()
    free = max(settings.DRY_RUN_SLOTS - running, 0)
    queued = DryRun.objects.filter(state=DryRun.State.QUEUED).order_by("pk")
    return list(queued.values_list("pk", flat=True)[:free])


# Rows per DELETE: a backlog is cleared in short transactions, not one long lock.
DELETE_BATCH = 500


def dry_runs_delete_expired(*, now: Any = None) -> int:
    """Delete the dry runs (their samples are in the row) that ended more than
    ``DRY_RUN_KEEP_S`` ago, or finished without an end recorded and were made that long ago;
    queued and running ones stay. Returns how many went. Safe twice (a second call finds
    none)."""
    cutoff = (now or timezone.now()) - timedelta(seconds=settings.DRY_RUN_KEEP_S)
    finished = DryRun.objects.filter(
        state__in=[DryRun.State.COMPLETED, DryRun.State.FAILED]
    ).filter(Q(ended_at__lt=cutoff) | Q(ended_at__isnull=True, created_at__lt=cutoff))
    deleted = 0
    while ids := list(finished.values_list("pk", flat=True)[:DELETE_BATCH]):
        deleted += DryRun.objects.filter(pk__in=ids).delete()[0]
    return deleted
