"""A request id per portal request, carried to the agent on every call and logged there
(a real agent process, logging JSON as in production)."""

from __future__ import annotations

import json
import logging
import logging.config
from collections.abc import Iterator
from typing import Any

import pytest

from core.logs import current_request_id, logging_config, request_id_bound
from portal.celery import _bind_request_id, _carry_request_id
from tests.basestation.processes import Agent, start_agent
from tests.conftest import sign_in_with_second_factor
from tests.factories import MobileResourceFactory, UserFactory

TOKEN = "request-id-agent-token-0123456789"


@pytest.fixture(scope="module")
def json_agent(tmp_path_factory) -> Iterator[Agent]:
    base = tmp_path_factory.mktemp("request-ids")
    agent = start_agent(
        base / "agent", base / "agent.log", AGENT_TOKEN=TOKEN, AGENT_LOG_FORMAT="json"
    )
    try:
        yield agent
    finally:
        agent.kill()


def _agent_lines(agent: Agent) -> list[dict[str, Any]]:
    lines = []
    for text in agent.log().splitlines():
        if text.startswith("{"):
            lines.append(json.loads(text))
    return lines


def _robot_status(client, agent: Agent, settings, **headers: str):
    settings.AGENT_TOKENS = {"default": TOKEN}
    MobileResourceFactory(name="mobile-1", agent_url=agent.url)
    sign_in_with_second_factor(client, UserFactory(is_staff=True))
    response = client.get("/api/v1/resources/mobile-1/robot/", headers=headers)
    assert response.status_code == 200, response.content
    return response


@pytest.mark.django_db
def test_a_request_id_given_to_the_portal_is_in_the_agents_log_line_of_each_call(
    client, json_agent, settings
):
    response = _robot_status(client, json_agent, settings, **{"X-Request-ID": "req-7f3a.1"})
    assert response["X-Request-ID"] == "req-7f3a.1"
    calls = [line for line in _agent_lines(json_agent) if line.get("request_id") == "req-7f3a.1"]
    # GET /status and GET /battery, each a JSON access line naming the call.
    assert sorted(line["path"] for line in calls) == ["/api/v1/battery", "/api/v1/status"]
    assert {line["logger"] for line in calls} == {"basestation.access"}
    assert {line["status"] for line in calls} == {200}


@pytest.mark.django_db
def test_without_one_the_portal_makes_a_request_id_and_the_agent_logs_that(
    client, json_agent, settings
):
    response = _robot_status(client, json_agent, settings, **{"X-Request-ID": "no spaces!"})
    made = response["X-Request-ID"]
    assert made != "no spaces!"  # not a plain token: replaced
    assert len(made) == 32
    paths = [line["path"] for line in _agent_lines(json_agent) if line.get("request_id") == made]
    assert sorted(paths) == ["/api/v1/battery", "/api/v1/status"]


def test_a_task_runs_under_the_request_id_of_whoever_queued_it_or_its_own():
    headers: dict[str, Any] = {}
    with request_id_bound("req-from-a-page"):
        _carry_request_id(headers=headers)
    assert headers == {"request_id": "req-from-a-page"}

    class _Task:
        class request:  # Celery's attribute name
            request_id = "req-from-a-page"

    _bind_request_id(task=_Task())
    assert current_request_id() == "req-from-a-page"
    _Task.request.request_id = None  # type: ignore[assignment]
    _bind_request_id(task=_Task())
    assert current_request_id() not in (None, "req-from-a-page")


def test_production_log_lines_are_json_with_the_request_id(capsys):
    config = logging_config(json_lines=True, level="INFO")
    logging.config.dictConfig(config)
    try:
        with request_id_bound("req-42"):
            logging.getLogger("portal.test").warning("staged %s", "run 5", extra={"run": 5})
    finally:
        logging.config.dictConfig(logging_config(json_lines=False, level="INFO"))
    line = json.loads(capsys.readouterr().err.strip().splitlines()[-1])
    assert line["message"] == "staged run 5"
    assert line["request_id"] == "req-42"
    assert line["level"] == "WARNING"
    assert line["logger"] == "portal.test"
    assert line["run"] == 5
