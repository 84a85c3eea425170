"""A running run's samples reach the live bus within a fraction of a second through the
collector (a long-poll on the agent), each stored and announced once — and a collector
killed mid-run loses nothing. Real processes: web, workers, beat, the collector, the agent,
PostgreSQL and a Redis server of the module's own.

The sweep runs every few seconds here, so promptness can only come from the collector.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from typing import Any

import pytest
import redis

from core.live import redis_channel, run_channel
from tests.factories import MobileResourceFactory
from tests.integration.experimenter import Experimenter
from tests.integration.stack import FAULT_ENV, Stack, private_stack
from tests.integration.test_faults import (
    assert_same_samples,
    wait_for,
    wait_state,
)

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

SWEEP_S = 4.0


@pytest.fixture(scope="module")
def live_stack(tmp_path_factory, django_db_setup):
    with private_stack(
        tmp_path_factory.mktemp("collector-stack"),
        extra_env={**FAULT_ENV, "RUN_SWEEP_INTERVAL_S": str(SWEEP_S)},
    ) as running:
        yield running


class Listener:
    """Every event on a run's channel, with when it arrived (this machine's clock)."""

    def __init__(self, stack: Stack, run_id: int) -> None:
        assert stack.redis is not None
        self.events: list[tuple[float, dict[str, Any]]] = []
        self._pubsub = redis.Redis.from_url(stack.redis.url(0)).pubsub(
            ignore_subscribe_messages=True
        )
        self._pubsub.subscribe(redis_channel(run_channel(run_id)))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._listen, daemon=True)
        self._thread.start()

    def _listen(self) -> None:
        while not self._stop.is_set():
            message = self._pubsub.get_message(timeout=0.2)
            if message is not None and message["type"] == "message":
                self.events.append((time.time(), json.loads(message["data"])))

    def drain(self, stack: Stack, seqs: list[int]) -> None:
        """Wait until an announcement of each of ``seqs`` has been read off the socket: a run
        counts as completed before its last announcements reach this listener, and samples a
        killed collector left unannounced are announced by the next one, not in order."""
        wait_for(
            f"samples 1 to {seqs[-1]} announced",
            stack,
            lambda: set(self.announced()) >= set(seqs),
            # Bounds a hang only: a clone with other work beside it took over 30 s.
            120,
        )

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._pubsub.close()

    def announced(self) -> Counter[int]:
        """How often each sequence number was announced as stored."""
        seen: Counter[int] = Counter()
        for _, event in self.events:
            if event["type"] == "samples":
                seen.update(range(event["first_seq"], event["last_seq"] + 1))
        return seen


@pytest.fixture
def robot(live_stack: Stack):
    return MobileResourceFactory(agent_url=live_stack.agent_url)


def test_samples_reach_the_live_bus_promptly_each_stored_and_announced_once(live_stack, robot):
    erin = Experimenter(live_stack, "erin")
    run_id = erin.run(robot.name, ahead_s=6.0, program_s=5.0)
    listener = Listener(live_stack, run_id)
    try:
        run = wait_state(live_stack, run_id, "completed", "interrupted", "failed")
        assert run.state == "completed", run.reason
        assert live_stack.agent is not None
        seqs = assert_same_samples(run_id, live_stack.agent)
        assert seqs == list(range(1, len(seqs) + 1))
        listener.drain(live_stack, seqs)
    finally:
        listener.close()
    assert listener.announced() == Counter(seqs)  # every sample announced, once
    # The collector announces what the agent commits as it commits it: many small batches.
    # The sweep (every 4 s here) would bring a 5 s program in two or three; how soon each
    # arrives is measured by `python -m bench live`, not asserted here.
    batches = [event for _, event in listener.events if event["type"] == "samples"]
    assert len(batches) >= 6, batches


def test_a_collector_killed_mid_run_loses_and_duplicates_nothing(live_stack, robot):
    erin = Experimenter(live_stack, "erin")
    run_id = erin.run(robot.name, ahead_s=6.0, program_s=10.0)
    listener = Listener(live_stack, run_id)
    assert live_stack.agent is not None
    agent = live_stack.agent
    try:
        wait_for("samples announced", live_stack, lambda: len(listener.announced()) >= 20, 30)
        live_stack.kill("collector")  # SIGKILL, mid long-poll
        recorded = agent.get_run(f"run-{run_id}")["sample_count"]
        wait_for(
            "the agent to record a backlog",
            live_stack,
            lambda: agent.get_run(f"run-{run_id}")["sample_count"] >= recorded + 60,
            20,
        )
        live_stack.start("collector")
        live_stack.wait_ready("collector")
        run = wait_state(live_stack, run_id, "completed", "interrupted", "failed")
        assert run.state == "completed", run.reason
        seqs = assert_same_samples(run_id, agent)
        assert seqs == list(range(1, len(seqs) + 1))
        assert run.agent_sample_count == len(seqs)
        listener.drain(live_stack, seqs)
    finally:
        listener.close()
    assert listener.announced() == Counter(seqs)
