"""Runs survive every fault, with real processes: web, workers, beat, two agents, PostgreSQL
and a Redis server of the module's own (``fault_stack``).

Each test books a run a few seconds ahead, injects one fault — a worker or an agent killed
with SIGKILL, Redis stopped, an agent down when its run is due, an e-stop — and then compares
the portal's stored samples with the agent's, sequence by sequence.
"""

from __future__ import annotations

import os
import re
import signal
import time
from collections import Counter
from collections.abc import Callable
from datetime import timedelta
from typing import Any, TypeVar

import pytest
import requests
from django.utils import timezone

from basestation.client import AgentClient, AgentError
from bench.stack import Proc
from bookings.models import Resource
from core.events.models import Event, EventCursor
from core.events.sequence import events_sequence
from core.webhooks.models import WebhookDelivery
from core.webhooks.services import webhook_create
from portal.runs.models import Run, Sample
from portal.runs.services.collection import MissingRange
from tests.core.webhook_receiver import Receiver
from tests.factories import FixedResourceFactory, MobileResourceFactory, UserFactory
from tests.integration.experimenter import Experimenter
from tests.integration.stack import FAULT_ENV, Stack

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

T = TypeVar("T")
PASSWORD = "correct horse battery"


def wait_for(what: str, stack: Stack, check: Callable[[], T | None], timeout_s: float) -> T:
    """Poll ``check`` until it returns something truthy; fail with the processes' logs."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}\n{stack.output()}")
        time.sleep(0.2)


def _run(run_id: int) -> Run:
    return Run.objects.get(pk=run_id)


def wait_state(stack: Stack, run_id: int, *states: str, timeout_s: float = 60) -> Run:
    return wait_for(
        f"run {run_id} to be {' or '.join(states)}",
        stack,
        lambda: (run := _run(run_id)).state in states and run,
        timeout_s,
    )


def wait_stored(stack: Stack, run_id: int, count: int) -> int:
    return wait_for(
        f"{count} samples of run {run_id} stored",
        stack,
        lambda: (n := Sample.objects.filter(run_id=run_id).count()) >= count and n,
        30,
    )


def assert_same_samples(run_id: int, agent: AgentClient) -> list[int]:
    """The portal holds exactly the agent's samples: each sequence once, same values."""
    on_agent = list(agent.iter_samples(f"run-{run_id}"))
    stored = list(
        Sample.objects.filter(run_id=run_id)
        .order_by("seq")
        .values_list("seq", "t", "velocity_mps", "track_m", "battery_v")
    )
    seqs = [row[0] for row in stored]
    assert not [seq for seq, n in Counter(seqs).items() if n > 1], "a sequence stored twice"
    assert seqs == [s["seq"] for s in on_agent]
    for (seq, t, velocity, track, battery), sample in zip(stored, on_agent, strict=True):
        assert (seq, velocity, track, battery) == (
            sample["seq"],
            sample["velocity_mps"],
            sample["track_m"],
            sample["battery_v"],
        )
        assert t.timestamp() == pytest.approx(sample["t"], abs=1e-6)
    return seqs


@pytest.fixture
def robots(fault_stack: Stack) -> tuple[Resource, Resource]:
    first = MobileResourceFactory(agent_url=fault_stack.agent_url)
    second = MobileResourceFactory(
        name="mobile-2", agent_url=fault_stack.agent2_url, agent_token_name="mobile-2"
    )
    return first, second


def test_a_worker_killed_mid_collection_and_restarted_stores_every_sample_once(fault_stack, robots):
    erin = Experimenter(fault_stack, "erin")
    run_id = erin.run("mobile-1", program_s=6.0)
    stored = wait_stored(fault_stack, run_id, 20)
    fault_stack.kill("worker")  # SIGKILL: tasks in hand are lost unacknowledged
    # The robot drives on: the agent records a backlog the dead worker does not collect.
    assert fault_stack.agent is not None
    wait_for(
        "the agent to record a backlog",
        fault_stack,
        lambda: fault_stack.agent.get_run(f"run-{run_id}")["sample_count"] >= stored + 40,
        20,
    )
    fault_stack.start("worker")
    fault_stack.wait_ready("worker")
    run = wait_state(fault_stack, run_id, "completed", "interrupted", "failed")
    assert run.state == "completed", run.reason
    seqs = assert_same_samples(run_id, fault_stack.agent)
    assert seqs == list(range(1, len(seqs) + 1))
    assert run.agent_sample_count == len(seqs)


REDIS_DOWN_S = 10.0


def test_redis_stopped_for_ten_seconds_mid_run_loses_and_duplicates_nothing(fault_stack, robots):
    erin = Experimenter(fault_stack, "erin")
    run_id = erin.run("mobile-1", program_s=16.0)
    wait_stored(fault_stack, run_id, 20)
    assert fault_stack.redis is not None
    assert fault_stack.agent is not None
    fault_stack.redis.stop()
    down_since = time.monotonic()
    # The fault lasts 10 s, and until the agent has recorded 100 more samples (5 s of
    # driving): the robot drives on without the portal.
    agent = fault_stack.agent
    recorded = agent.get_run(f"run-{run_id}")["sample_count"]
    while time.monotonic() - down_since < REDIS_DOWN_S:
        time.sleep(0.5)
    wait_for(
        "the agent to record on while Redis is down",
        fault_stack,
        lambda: agent.get_run(f"run-{run_id}")["sample_count"] > recorded + 100,
        20,
    )
    fault_stack.redis.start()
    run = wait_state(fault_stack, run_id, "completed", "interrupted", "failed", timeout_s=90)
    assert run.state == "completed", run.reason
    seqs = assert_same_samples(run_id, fault_stack.agent)
    assert seqs == list(range(1, len(seqs) + 1))
    health = requests.get(f"{fault_stack.web}/healthz", timeout=10).json()
    assert health["cache"] == "ok", health
    # Every process waited Redis out: none exited (a worker that did would take the next
    # tests' runs with it, as nothing restarts it here).
    exited = {
        name: p.popen.returncode
        for name, p in fault_stack.procs.items()
        if p.popen.poll() is not None
    }
    assert not exited, f"exited during the outage: {exited}\n{fault_stack.output()}"


def _agent_down(stack: Stack) -> None:
    stack.kill("agent", signal.SIGTERM)
    assert stack.agent is not None
    with pytest.raises(AgentError):
        stack.agent.healthz()


def _agent_up(stack: Stack) -> None:
    stack.start("agent")
    stack.wait_ready("agent")


def test_an_agent_down_at_staging_and_back_before_the_start_runs_the_run(fault_stack, robots):
    _agent_down(fault_stack)
    erin = Experimenter(fault_stack, "erin")
    run_id = erin.run("mobile-1", ahead_s=8.0, program_s=3.0)
    worker = fault_stack.procs["worker"]
    worker.wait_for_line(lambda line: "run_stage" in line and "retry in" in line, 20)
    assert _run(run_id).state == "scheduled"
    _agent_up(fault_stack)
    run = wait_state(fault_stack, run_id, "completed", "interrupted", "failed")
    assert run.state == "completed", run.reason
    assert fault_stack.agent is not None
    assert_same_samples(run_id, fault_stack.agent)


def test_an_agent_down_past_the_start_and_its_grace_fails_the_run_and_tells_the_owner(
    fault_stack, robots
):
    _agent_down(fault_stack)
    mail = fault_stack.procs["mail"]
    since = mail.mark()  # the module's earlier mails are not this run's
    try:
        erin = Experimenter(fault_stack, "erin")
        run_id = erin.run("mobile-1", ahead_s=2.0, program_s=6.0)
        run = wait_state(fault_stack, run_id, "staged", "failed", timeout_s=30)
        assert run.state == "failed"
        grace_s = float(FAULT_ENV["RUN_START_GRACE_S"])
        assert f"could not be reached by {grace_s:g} s after the run's start" in run.reason
        assert "ConnectionError" in run.reason
        assert Sample.objects.filter(run_id=run_id).count() == 0
        told = mail.wait_for_mail(lambda m: m["Subject"].startswith("Run failed:"), 30, since=since)
        assert told["Subject"] == f"Run failed: {run.title}"
        assert told["To"] == "erin@example.org"
        assert run.reason in told.get_content()
    finally:
        _agent_up(fault_stack)


def _page_of(stack: Stack, username: str, path: str) -> str:
    """A page as a logged-in browser gets it (session login through the form)."""
    session = requests.Session()
    login_url = f"{stack.web}/accounts/login/"
    token = re.search(
        r'name="csrfmiddlewaretoken" value="([^"]+)"', session.get(login_url, timeout=10).text
    )
    assert token
    session.post(
        login_url,
        data={"csrfmiddlewaretoken": token.group(1), "login": username, "password": PASSWORD},
        headers={"Referer": login_url},
        timeout=10,
    )
    page = session.get(f"{stack.web}{path}", timeout=10)
    assert page.status_code == 200, page.text[:500]
    return page.text


def test_an_agent_killed_mid_run_interrupts_the_run_keeping_every_sample_up_to_the_kill(
    fault_stack, robots
):
    erin = Experimenter(fault_stack, "erin")
    run_id = erin.run("mobile-1", program_s=8.0)
    wait_stored(fault_stack, run_id, 20)
    fault_stack.kill("agent")  # SIGKILL mid-run; the robot's dead-man stops it
    _agent_up(fault_stack)  # as its supervisor restarts it
    run = wait_state(fault_stack, run_id, "completed", "interrupted", "failed")
    assert run.state == "interrupted", run.reason
    assert fault_stack.agent is not None
    on_agent = fault_stack.agent.get_run(f"run-{run_id}")
    assert on_agent["state"] == "interrupted"
    seqs = assert_same_samples(run_id, fault_stack.agent)
    assert seqs == list(range(1, on_agent["last_seq"] + 1))
    assert len(seqs) < 8.0 * 20  # it stopped before the program's end
    [tail] = [MissingRange(**m) for m in run.missing]
    assert (tail.first_seq, tail.last_seq) == (seqs[-1] + 1, None)
    assert tail.to_s == pytest.approx(8.0)
    assert "agent restarted during run" in run.reason
    page = _page_of(fault_stack, "erin", f"/runs/{run_id}/")
    assert 'data-state="interrupted"' in page
    assert "agent restarted during run" in page
    assert f"seq {seqs[-1] + 1} onwards (from {tail.from_s:.1f} s to 8.0 s)" in page


def test_two_robots_run_at_the_same_time_each_with_its_own_data(fault_stack, robots):
    erin, finn = Experimenter(fault_stack, "erin"), Experimenter(fault_stack, "finn")
    start = timezone.now() + timedelta(seconds=4)
    first = erin.run("mobile-1", start=start, program_s=4.0)
    second = finn.run("mobile-2", start=start, program_s=4.0)
    assert fault_stack.agent is not None
    assert fault_stack.agent2 is not None
    for run_id, agent, other in (
        (first, fault_stack.agent, fault_stack.agent2),
        (second, fault_stack.agent2, fault_stack.agent),
    ):
        run = wait_state(fault_stack, run_id, "completed", "interrupted", "failed")
        assert run.state == "completed", run.reason
        assert_same_samples(run_id, agent)
        with pytest.raises(AgentError) as unknown:
            other.get_run(f"run-{run_id}")
        assert unknown.value.status == 404
    one, two = _run(first), _run(second)
    assert (one.start_at, one.end_at) == (two.start_at, two.end_at)
    # Two rails: each run's positions wrap at its own robot's rail.
    assert one.rail_length_m == pytest.approx(120.0, abs=0.1)
    assert two.rail_length_m == pytest.approx(79.9, abs=0.1)
    assert max(Sample.objects.filter(run=two).values_list("track_m", flat=True)) < 80


def test_an_estop_report_takes_the_robot_out_of_booking(fault_stack, robots):
    _, second = robots
    UserFactory(username="root", is_staff=True, email="root@example.org")
    erin = Experimenter(fault_stack, "erin")
    assert fault_stack.agent2 is not None
    mail = fault_stack.procs["mail"]
    since = mail.mark()
    try:
        fault_stack.agent2.stop(user="carol", reason="someone on the roof")
        # The next status check holds it (how soon is `make bench`'s to measure); the
        # deadline only bounds a hang.
        reason = wait_for(
            "the hold", fault_stack, lambda: Resource.objects.get(pk=second.pk).hold_reason, 30
        )
        assert reason == "emergency stop latched: someone on the roof (by carol)"
        refused = erin.book("mobile-2", ahead_s=60, program_s=4)
        assert refused.status_code == 400, refused.text
        assert f"mobile-2 is out of service: {reason}." in refused.text
        held = mail.wait_for_mail(
            lambda m: m["Subject"].startswith("mobile-2 out of booking"), 20, since=since
        )
        assert held["Subject"] == f"mobile-2 out of booking: {reason}"
        assert held["To"] == "root@example.org"  # the one admin with an address
    finally:
        fault_stack.agent2.release_stop()


def _confirmed(mail: Proc, nodes: list[Resource]) -> int:
    """How many of ``nodes``' bookings the mail worker has confirmed by e-mail."""
    sent = [line for line in mail.lines if line.startswith("your booking of ")]
    return sum(
        any(line.startswith(f"your booking of {n.name} on ") for line in sent) for n in nodes
    )


def test_a_mail_backlog_does_not_delay_a_run(fault_stack, robots):
    """Mail has its own queue and worker: with the mail worker stuck and mails piling up, a
    run is staged and collected on time; the mails go out once the worker moves again."""
    mail = fault_stack.procs["mail"]
    os.killpg(mail.popen.pid, signal.SIGSTOP)  # stuck, as on a mail server that never answers
    erin = Experimenter(fault_stack, "erin")
    nodes = [FixedResourceFactory() for _ in range(20)]
    try:
        start = timezone.now() + timedelta(hours=2)
        for node in nodes:  # each booking queues its "confirmed" mail
            booked = erin.session.post(
                f"{fault_stack.web}/api/v1/reservations/",
                json={
                    "resources": [node.name],
                    "start_at": start.isoformat(),
                    "end_at": (start + timedelta(hours=1)).isoformat(),
                },
                timeout=10,
            )
            assert booked.status_code == 201, booked.text
        run_id = erin.run("mobile-1", program_s=3.0)
        run = wait_state(fault_stack, run_id, "completed", "interrupted", "failed", timeout_s=30)
        assert run.state == "completed", run.reason
        assert _confirmed(mail, nodes) == 0
    finally:
        os.killpg(mail.popen.pid, signal.SIGCONT)
    wait_for(
        "the mails of the backlog",
        fault_stack,
        lambda: _confirmed(mail, nodes) == len(nodes),
        30,
    )


RECEIVER_DOWN_S = 60.0


def test_webhooks_deliver_every_event_through_a_killed_mail_worker_and_a_minute_down(
    fault_stack, robots, tmp_path
):
    """A run's events sent to a webhook receiver (a process of its own): the mail worker is
    killed while the receiver holds its answer to the first delivery, and the receiver is then
    down for a minute while the run goes on. Every event still arrives, signed, at least once,
    the cut one again with its id, each first accepted in order; none is lost."""
    wendy = Experimenter(fault_stack, "wendy")
    receiver = Receiver(tmp_path, "whsec_" + "A" * 32, HOLD_FIRST_S="4")
    receiver.start()
    subscription, secret = webhook_create(owner=wendy.user, url=receiver.url)
    receiver.stop()
    receiver.secret = secret
    receiver.start()  # the same port, now verifying with the webhook's own secret
    try:
        run_id = wendy.run("mobile-1", program_s=3.0)
        cut = wait_for("the first delivery", fault_stack, receiver.received, 30)[0]
        fault_stack.kill("mail")  # SIGKILL mid-delivery: the receiver has not answered yet
        receiver.stop()
        down_at = time.monotonic()
        fault_stack.start("mail")
        fault_stack.wait_ready("mail")
        run = wait_state(fault_stack, run_id, "completed", "interrupted", "failed")
        assert run.state == "completed", run.reason
        wait_for(
            "a try while the receiver is down",
            fault_stack,
            lambda: WebhookDelivery.objects.filter(
                subscription=subscription, attempts__gt=0, last_error__startswith="no answer"
            ).exists(),
            RECEIVER_DOWN_S,
        )
        # The fault lasts its minute (nothing is asserted on the wait).
        time.sleep(max(0.0, down_at + RECEIVER_DOWN_S - time.monotonic()))
        receiver.start()

        def delivered() -> set[int] | None:
            events_sequence()  # number what has committed, as every reader does
            mine = set(Event.objects.filter(owner=wendy.user).values_list("position", flat=True))
            done = set(
                WebhookDelivery.objects.filter(
                    subscription=subscription, state="delivered"
                ).values_list("event__position", flat=True)
            )
            ready = Event.objects.filter(type="run.data_ready", subject=f"run:{run_id}").exists()
            return mine if ready and mine == done else None

        deadline = time.monotonic() + 60
        while (events := delivered()) is None:
            assert time.monotonic() < deadline, _webhook_state(subscription, wendy.user)
            time.sleep(0.2)
    finally:
        receiver.stop()
    got = receiver.received()
    assert all(line["verified"] for line in got), got
    accepted = [line["id"] for line in got if line["answer"] == 200]
    assert set(accepted) == events  # none lost
    assert [line["webhook_id"] for line in got].count(cut["webhook_id"]) >= 2  # sent again
    firsts = list(dict.fromkeys(accepted))
    assert firsts == sorted(firsts)  # each first accepted in the order of the events
    assert (
        WebhookDelivery.objects.get(subscription=subscription, event__position=cut["id"]).attempts
        >= 2
    )


def _webhook_state(subscription: Any, owner: Any) -> str:
    """What a webhook test that timed out saw: the owner's events, their deliveries, the
    handlers' cursors."""
    lines = ["events:"]
    for event in Event.objects.filter(owner=owner).order_by("position"):
        lines.append(f"  {event.position} {event.type} {event.subject} at {event.occurred_at}")
    lines.append("deliveries:")
    for d in WebhookDelivery.objects.filter(subscription=subscription).order_by("pk"):
        lines.append(
            f"  event {d.event.position} {d.state} tries={d.attempts} status={d.last_status} "
            f"error={d.last_error!r} next={d.next_try_at}"
        )
    lines.append(f"cursors: {list(EventCursor.objects.values_list('handler', 'position'))}")
    return "\n".join(lines)
