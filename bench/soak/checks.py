"""What the soak checks at the end, each a list of misses (``model.CHECKS``)."""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any

import redis

from basestation.client import AgentError
from bench.soak.model import (
    END_STATES,
    QUEUE_WORKERS,
    ROBOTS,
    RunRecord,
    SoakResult,
)

if TYPE_CHECKING:
    from bench.soak.system import Soak


def check(soak: Soak) -> SoakResult:
    from django.db import connections

    from bench.__main__ import machine  # the benches' command: loaded only when needed

    connections.close_all()
    runs = _check_runs(soak)
    _check_duplicates(soak)
    _check_keys(soak)
    leases, orphans, unheld = _check_leases(soak)
    _check_tasks(soak)
    _check_holds(soak)
    return SoakResult(
        minutes=soak.minutes,
        seed=soak.seed,
        started_at=soak.started_at.isoformat(timespec="seconds"),
        machine=machine(),
        faults=soak.faults,
        restarts=soak.restarts,
        bookings=soak.bookings,
        runs=runs,
        holds=soak.holds,
        misses=soak.misses,
        samples_stored=sum(r.samples for r in runs),
        samples_on_agents=sum(r.agent_samples for r in runs),
        leases=leases,
        orphan_leases=orphans,
        bookings_without_lease=unheld,
        awaiting_redelivery=soak.awaiting_redelivery,
    )


def _check_runs(soak: Soak) -> list[RunRecord]:
    from portal.runs.models import Run, Sample

    records = []
    booked = {b.run_id: b for b in soak.bookings if b.run_id is not None}
    for run in Run.objects.filter(pk__in=list(booked)).select_related("resource"):
        booking = booked[run.pk]
        if run.state not in END_STATES:
            soak.miss("runs_ended", f"run {run.pk} is {run.state}")
        agent = soak.agents[booking.robot]
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
            (s["seq"], s["t"], s["velocity_mps"], s["track_m"], s["battery_v"]) for s in on_agent
        ]
        got = [(seq, t.timestamp(), v, track, battery) for seq, t, v, track, battery in stored]
        if not _same_samples(got, expected):
            lost = sorted({s[0] for s in expected} - {s[0] for s in got})
            extra = sorted({s[0] for s in got} - {s[0] for s in expected})
            soak.miss(
                "samples_exact",
                f"run {run.pk} ({run.state}): {len(got)} stored, {len(expected)} on the "
                f"agent; lost {_ranges(lost)}, not on the agent {_ranges(extra)}",
            )
        if run.state == "completed":
            seqs = [s[0] for s in expected]
            if seqs != list(range(1, len(seqs) + 1)) or not seqs:
                soak.miss("samples_exact", f"run {run.pk} completed with gaps on the agent")
        if run.state == "interrupted":
            gaps = _agent_gaps(
                [s[0] for s in expected],
                agent_last_seq=int(agent_run["last_seq"] or 0) if agent_run else 0,
                ended_early=agent_run is None or agent_run["state"] != "completed",
            )
            missing = [(m["first_seq"], m["last_seq"]) for m in run.missing]
            if missing != gaps:
                soak.miss(
                    "missing_equals_gaps",
                    f"run {run.pk}: missing {missing}, the agent's gaps {gaps}",
                )
        records.append(
            RunRecord(
                id=run.pk,
                robot=booking.robot,
                nodes=booking.nodes,
                start_s=(run.start_at - soak.started_at).total_seconds(),
                end_s=(run.end_at - soak.started_at).total_seconds(),
                state=run.state,
                samples=len(got),
                agent_samples=len(expected),
                reason=run.reason,
            )
        )
    missing_runs = set(booked) - {r.id for r in records}
    for run_id in sorted(missing_runs):
        soak.miss("runs_ended", f"run {run_id} was booked (201) but does not exist")
    return sorted(records, key=lambda r: r.start_s)


def _check_duplicates(soak: Soak) -> None:
    from django.db.models import Count

    from portal.runs.models import Sample

    doubled = (
        Sample.objects.values("run_id", "seq")
        .annotate(n=Count("id"))
        .filter(n__gt=1)
        .order_by("run_id", "seq")
    )
    for row in doubled[:20]:
        soak.miss("no_duplicates", f"run {row['run_id']} seq {row['seq']} stored {row['n']}×")


def _check_keys(soak: Soak) -> None:
    from bookings.models import Reservation
    from core.audit.models import IdempotencyKey

    keys = {
        k.key: k
        for k in IdempotencyKey.objects.filter(user__username="soak", path="/api/v1/reservations/")
    }
    by_reservation = Counter(
        int(k.response["id"]) for k in keys.values() if k.status == 201 and k.response
    )
    for reservation_id, n in by_reservation.items():
        if n > 1:
            soak.miss("keys_once", f"reservation {reservation_id} answered to {n} keys")
    reservations = set(
        Reservation.objects.filter(owner__username="soak").values_list("pk", flat=True)
    )
    for reservation_id in sorted(reservations - set(by_reservation)):
        soak.miss("keys_once", f"reservation {reservation_id} was booked under no key")
    for booking in soak.bookings:
        stored = keys.get(booking.key)
        answer = stored.response if stored is not None and stored.status == 201 else None
        held = int(answer["id"]) if isinstance(answer, dict) else None
        if booking.reservation_id is not None and held != booking.reservation_id:
            soak.miss(
                "keys_once",
                f"{booking.key}: answered reservation {booking.reservation_id}, "
                f"the key holds {held}",
            )
        elif booking.reservation_id is None and held is not None:
            soak.miss(
                "keys_once",
                f"{booking.key}: refused to the client ({booking.refused}) yet booked "
                f"reservation {held}",
            )


def _check_leases(soak: Soak) -> tuple[int, int, int]:
    """The portal's leases on the stand-in against its bookings: how many leases, how
    many hold nodes for no booking, how many bookings are not held by theirs."""
    from django.conf import settings

    from bookings.leases import public_id_of, scheduler_client
    from bookings.models import Reservation
    from bookings.scheduler import ALL_STATUSES

    assert settings.SCHEDULER is not None
    with scheduler_client() as scheduler:
        leases = scheduler.list_leases(
            window_start=soak.started_at - timedelta(hours=1),
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
            soak.miss(
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
            soak.miss(
                "leases_match",
                f"reservation {booking.pk} ({booking.state}) has no lease holding its nodes "
                f"({own.status.value if own else 'none on the scheduler'})",
            )
        elif own.valid_from > booking.start_at or own.valid_until < booking.end_at:
            unheld += 1
            soak.miss("leases_match", f"reservation {booking.pk}: its lease does not cover it")
    return len(ours), orphans, unheld


def _check_tasks(soak: Soak) -> None:
    """The broker drains: both queues empty at some moment, and no task taken but
    unacknowledged for longer than a task may last — except those a killed worker had
    taken, which Redis hands out again after the visibility timeout (their work is redone
    meanwhile by the sweeps, as the checks of the runs show); those are listed."""
    from django.conf import settings

    client = redis.Redis.from_url(soak.redis.url(1))
    longest_task_s = 300.0  # the longest time limit of any task (the daily clean-up)
    visibility_s = float(settings.CELERY_VISIBILITY_TIMEOUT_S)
    deadline = time.monotonic() + 60
    while True:
        queued = {queue: client.llen(queue) for queue in QUEUE_WORKERS}
        now_s = time.time()
        stuck, awaiting = [], []
        for task, queue, taken_s in _unacknowledged(client):
            killed_s = _last_kill_epoch_s(soak, QUEUE_WORKERS.get(queue, ""))
            held_by_dead = killed_s is not None and taken_s <= killed_s
            age_s = now_s - taken_s
            if held_by_dead and age_s <= visibility_s:
                awaiting.append(f"{task} ({queue}, taken {age_s:.0f} s ago)")
            elif age_s > (visibility_s if held_by_dead else longest_task_s):
                stuck.append(f"{task} ({queue}, taken {age_s:.0f} s ago)")
        if not any(queued.values()) and not stuck:
            soak.awaiting_redelivery = awaiting
            return
        if time.monotonic() > deadline:
            soak.miss("no_task_stuck", f"queued {queued}; unacknowledged: {stuck}")
            soak.awaiting_redelivery = awaiting
            return
        time.sleep(1.0)


def _last_kill_epoch_s(soak: Soak, process: str) -> float | None:
    kills = [f.at_s for f in soak.faults if f.target == process]
    redis_lost = [f.at_s for f in soak.faults if f.kind == "redis"]
    # A Redis crash loses what it held, unacknowledged messages with it.
    if not kills or (redis_lost and max(redis_lost) > max(kills)):
        return None
    return soak.started_at.timestamp() + max(kills)


def _check_holds(soak: Soak) -> None:
    from bookings.models import Resource

    soak._operator_look()
    for hold in soak.holds:
        if hold["explained_by"] is None:
            soak.miss("holds_explained", f"{hold['robot']}: {hold['reason']}")
    for robot in Resource.objects.filter(name__in=list(ROBOTS)).exclude(hold_reason=""):
        if not any(h["robot"] == robot.name for h in soak.holds):
            soak.miss("holds_explained", f"{robot.name} held: {robot.hold_reason}")


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
