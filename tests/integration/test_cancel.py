"""A booking cancelled over the public API while its run drives the robot, with real
processes: the web server's commit hook queues the withdrawal, the worker aborts the run on
the agent, the agent ramps the simulated robot to a stop, and the portal collects the run
as interrupted with every sample the agent recorded.
"""

from __future__ import annotations

import time

import pytest

from tests.factories import MobileResourceFactory
from tests.integration.experimenter import Experimenter
from tests.integration.test_faults import assert_same_samples, wait_for, wait_state

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]


def test_cancelling_a_running_run_over_the_api_aborts_it_and_stops_the_robot(stack):
    MobileResourceFactory(agent_url=stack.agent_url)
    agent = stack.agent
    erin = Experimenter(stack, "erin")
    booked = erin.book("mobile-1", ahead_s=3.0, program_s=30.0)
    assert booked.status_code == 201, booked.text
    reservation_id, run_id = booked.json()["id"], booked.json()["run"]["id"]
    agent_run_id = f"run-{run_id}"

    def driving() -> bool:
        status = agent.status()
        robot = status["robot"]
        return (
            status["current_run"] == agent_run_id
            and (robot["velocity_mps"] or 0) > 0.2
            and (robot["commanded_velocity_mps"] or 0) > 0.2
        )

    wait_for("the robot to drive the run", stack, driving, 30)
    cancelled_at = time.monotonic()
    cancelled = erin.session.delete(
        f"{stack.web}/api/v1/reservations/{reservation_id}/",
        params={"reason": "wrong program"},
        timeout=10,
    )
    assert cancelled.status_code == 200, cancelled.text
    assert cancelled.json()["state"] == "cancelled"

    ended = wait_for(
        "the agent's run to end",
        stack,
        lambda: (run := agent.get_run(agent_run_id))["state"] != "running" and run,
        15,
    )
    assert ended["state"] == "aborted", ended
    assert time.monotonic() - cancelled_at < 15

    def at_rest() -> dict | None:
        status = agent.status()
        robot = status["robot"]
        stopped = robot["commanded_velocity_mps"] == 0.0 and robot["velocity_mps"] == 0.0
        return status if stopped and status["current_run"] is None else None

    wait_for("the robot commanded to a stop", stack, at_rest, 15)

    run = wait_state(stack, run_id, "completed", "interrupted", "failed", "cancelled")
    assert run.state == "interrupted", run.reason
    on_agent = agent.get_run(agent_run_id)
    seqs = assert_same_samples(run_id, agent)
    assert seqs == list(range(1, on_agent["last_seq"] + 1))
    assert len(seqs) < 30.0 * 20  # stopped well before the program's end
