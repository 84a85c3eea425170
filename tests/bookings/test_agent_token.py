"""``manage.py agent_token``: each robot's token stored by the portal, the digests its agent
keeps, rotation without a refused call, revocation; against real agents over HTTP."""

from __future__ import annotations

import contextlib
import re
import threading
from collections.abc import Callable, Iterator
from io import StringIO
from pathlib import Path

import pytest
from django.core.management import CommandError, call_command
from werkzeug.serving import make_server

from basestation.app import create_app
from basestation.client import AgentClient, AgentUnauthorized
from basestation.config import AgentConfig
from basestation.runtime import get_runtime
from bookings.agent_tokens import token_sha256
from bookings.models import AgentCredential, Resource
from portal.runs.agents import AgentNotConfigured, agent_client_for, agent_token_for
from tests.factories import FixedResourceFactory, MobileResourceFactory

pytestmark = pytest.mark.django_db

ENV_TOKEN = "the-environments-token-0123456789abcdef"


def _command(*args: str) -> str:
    out = StringIO()
    call_command("agent_token", *args, stdout=out)
    return out.getvalue()


def _digests(printed: str) -> list[str]:
    found = re.search(r"AGENT_TOKEN_SHA256=([0-9a-f,]+)", printed)
    assert found, printed
    return found.group(1).split(",")


@contextlib.contextmanager
def _agent(data_dir: Path, digests: list[str]) -> Iterator[str]:
    """A real agent over HTTP that holds only ``digests`` (as AGENT_TOKEN_SHA256 says)."""
    config = AgentConfig(token_sha256=tuple(digests), data_dir=data_dir, robot="simple")
    app = create_app(config, start_control_loop=False)
    server = make_server("127.0.0.1", 0, app, threaded=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_port}"
    finally:
        server.shutdown()
        thread.join()
        server.server_close()
        get_runtime(app).close()


def _status_ok(client: AgentClient) -> bool:
    try:
        client.status()
    except AgentUnauthorized:
        return False
    return True


@pytest.fixture
def robots(settings) -> tuple[Resource, Resource]:
    settings.AGENT_TOKENS = {"default": ENV_TOKEN}
    return (
        MobileResourceFactory(name="mobile-1", agent_url="http://127.0.0.1:9"),
        MobileResourceFactory(name="mobile-2", agent_url="http://127.0.0.1:9"),
    )


def _pointed(resource: Resource, url: str) -> Resource:
    Resource.objects.filter(pk=resource.pk).update(agent_url=url)
    resource.refresh_from_db()
    return resource


def test_each_robot_gets_its_own_token_stored_encrypted_and_only_digests_are_printed(robots):
    one, two = robots
    printed = _command("issue", "mobile-1") + _command("issue", "mobile-2")
    token_one, token_two = agent_token_for(one), agent_token_for(two)
    assert token_one != token_two
    assert len(token_one) >= 40
    # Printed: the digests, never the tokens; stored: neither the token nor its digest.
    assert _digests(printed.split("mobile-2 has")[0]) == [token_sha256(token_one)]
    assert token_one not in printed
    assert token_two not in printed
    stored = AgentCredential.objects.get(resource=one).token_encrypted
    assert token_one not in stored
    assert token_sha256(token_one) not in stored
    assert _digests(_command("show", "mobile-1")) == [token_sha256(token_one)]


def test_agent_a_refuses_agent_bs_token(robots, tmp_path):
    one, two = robots
    digest_one = _digests(_command("issue", "mobile-1"))
    digest_two = _digests(_command("issue", "mobile-2"))
    with _agent(tmp_path / "a", digest_one) as url_a, _agent(tmp_path / "b", digest_two) as url_b:
        one, two = _pointed(one, url_a), _pointed(two, url_b)
        assert _status_ok(agent_client_for(one))
        assert _status_ok(agent_client_for(two))
        # Each agent's token at the other agent: refused.
        assert not _status_ok(AgentClient(url_b, agent_token_for(one)))
        assert not _status_ok(AgentClient(url_a, agent_token_for(two)))


def test_a_rotation_refuses_no_call_and_the_old_token_is_refused_after_it(robots, tmp_path):
    one, _ = robots
    first_digests = _digests(_command("issue", "mobile-1"))
    old_token = agent_token_for(one)
    with _agent(tmp_path / "before", first_digests) as url:
        assert _status_ok(agent_client_for(_pointed(one, url)))
        started = _command("rotate", "mobile-1")
        # The portal keeps presenting the current token until the agent accepts both.
        assert agent_token_for(one) == old_token
        assert _status_ok(agent_client_for(one))
    both = _digests(started)
    assert both[0] == first_digests[0]
    assert len(both) == 2
    with _agent(tmp_path / "during", both) as url:
        one = _pointed(one, url)
        assert _status_ok(agent_client_for(one))  # still the old token
        finished = _command("rotate", "mobile-1", "--finish")
        new_token = agent_token_for(one)
        assert new_token != old_token
        assert _status_ok(agent_client_for(one))  # the new token, same agent
        assert _status_ok(AgentClient(url, old_token))  # the old one still works here
    assert _digests(finished) == [token_sha256(new_token)] == both[1:]
    with _agent(tmp_path / "after", _digests(finished)) as url:
        assert _status_ok(agent_client_for(_pointed(one, url)))
        assert not _status_ok(AgentClient(url, old_token))


def test_rotation_steps_out_of_order_are_refused_and_change_nothing(robots):
    with pytest.raises(CommandError, match="no stored agent token: issue one first"):
        _command("rotate", "mobile-1")
    _command("issue", "mobile-1")
    with pytest.raises(CommandError, match="already has a stored agent token"):
        _command("issue", "mobile-1")
    with pytest.raises(CommandError, match="no rotation"):
        _command("rotate", "mobile-1", "--finish")
    before = AgentCredential.objects.get(resource__name="mobile-1").token_encrypted
    _command("rotate", "mobile-1")
    with pytest.raises(CommandError, match="already under way"):
        _command("rotate", "mobile-1")
    assert AgentCredential.objects.get(resource__name="mobile-1").token_encrypted == before


def test_revoking_falls_back_to_the_environment_and_names_the_digests_to_drop(robots, settings):
    one, _ = robots
    issued = _digests(_command("issue", "mobile-1"))
    printed = _command("revoke", "mobile-1")
    assert issued[0] in printed
    assert agent_token_for(one) == ENV_TOKEN
    settings.AGENT_TOKENS = {}
    with pytest.raises(AgentNotConfigured, match="not configured"):
        agent_client_for(one)


def test_a_deployment_on_the_environments_token_moves_to_a_stored_one_unchanged(robots):
    one, _ = robots
    assert agent_token_for(one) == ENV_TOKEN  # as before: AGENT_TOKEN
    printed = _command("issue", "mobile-1", "--from-environment")
    assert _digests(printed) == [token_sha256(ENV_TOKEN)]
    assert AgentCredential.objects.filter(resource=one).exists()
    assert agent_token_for(one) == ENV_TOKEN


def test_a_token_stored_under_another_secret_key_is_a_clear_error_until_its_fallback(
    robots, settings
):
    one, _ = robots
    _command("issue", "mobile-1")
    token = agent_token_for(one)
    old_key = settings.SECRET_KEY
    settings.SECRET_KEY = "a-new-secret-key-" + "x" * 40
    with pytest.raises(AgentNotConfigured, match="cannot be decrypted"):
        agent_token_for(one)
    settings.SECRET_KEY_FALLBACKS = [old_key]
    assert agent_token_for(one) == token
    # Unreadable for good (its key lost): it can still be revoked.
    settings.SECRET_KEY_FALLBACKS = []
    assert "could not be decrypted" in _command("revoke", "mobile-1")
    assert not AgentCredential.objects.filter(resource=one).exists()


@pytest.mark.parametrize(
    "args",
    [("issue", "node-1"), ("show", "nobody"), ("revoke", "mobile-9")],
    ids=["fixed node", "unknown", "unknown robot"],
)
def test_only_robots_have_agent_tokens(args: tuple[str, ...]):
    FixedResourceFactory(name="node-1")
    with pytest.raises(CommandError, match="no robot named"):
        _command(*args)


def test_options_only_go_with_their_action(robots):
    check: Callable[..., object] = _command
    with pytest.raises(CommandError, match="--finish goes with rotate"):
        check("issue", "mobile-1", "--finish")
    with pytest.raises(CommandError, match="--from-environment goes with issue"):
        check("rotate", "mobile-1", "--from-environment")
