"""The roof map's data: the robot's rail relayed from its agent, for the pages and the API,
for a signed-in user, anonymous, and with the agent down."""

from __future__ import annotations

import pytest

from tests.factories import FixedResourceFactory, MobileResourceFactory
from tests.runs.conftest import agent  # noqa: F401  (the in-process agent fixture)

pytestmark = pytest.mark.django_db


def test_the_page_and_the_api_relay_the_agents_rail_and_keep_it(client, owner, agent, settings):  # noqa: F811
    robot = MobileResourceFactory(agent_url=agent.url)
    client.force_login(owner)
    page = client.get(f"/rails/{robot.name}.json").json()
    # The in-process agent runs the kinematic model: a length, no geometry.
    assert page == {"available": True, "robot": robot.name, "geometry": False, "length_m": 120.0}
    api = client.get(f"/api/v1/resources/{robot.name}/rail/")
    assert api.status_code == 200
    assert api.json() == {"geometry": False, "length_m": 120.0}
    # Kept a few minutes: the agent is not asked again for every viewer.
    settings.AGENT_TOKENS = {"default": "wrong"}
    assert client.get(f"/rails/{robot.name}.json").json()["available"] is True


def test_an_unreachable_agent_is_said_on_the_page_and_503_in_the_api(client, owner, settings):
    settings.AGENT_TOKENS = {"default": "t" * 32}
    robot = MobileResourceFactory(agent_url="http://127.0.0.1:1")
    client.force_login(owner)
    page = client.get(f"/rails/{robot.name}.json")
    assert page.status_code == 200
    assert page.json()["available"] is False
    assert "did not give its rail" in page.json()["detail"]
    assert client.get(f"/api/v1/resources/{robot.name}/rail/").status_code == 503


def test_only_signed_in_users_and_only_mobile_nodes(client, owner):
    robot = MobileResourceFactory()
    node = FixedResourceFactory()
    assert client.get(f"/rails/{robot.name}.json").status_code == 302
    assert client.get(f"/api/v1/resources/{robot.name}/rail/").status_code in (401, 403)
    client.force_login(owner)
    assert client.get(f"/rails/{node.name}.json").status_code == 404
    response = client.get(f"/api/v1/resources/{node.name}/rail/")
    assert response.status_code == 400
    assert "not a mobile node" in response.content.decode()
