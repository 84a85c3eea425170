"""``manage.py agent_token issue``: a robot's token and the digest its agent keeps."""

from __future__ import annotations

import hashlib
import re
from io import StringIO

import pytest
from django.core.management import CommandError, call_command

from tests.factories import FixedResourceFactory, MobileResourceFactory

pytestmark = pytest.mark.django_db


def _issue(name: str) -> str:
    out = StringIO()
    call_command("agent_token", "issue", name, stdout=out)
    return out.getvalue()


def test_the_token_and_its_digest_match_and_each_issue_is_new():
    MobileResourceFactory(name="mobile-2", agent_token_name="mobile-2")
    printed = _issue("mobile-2")
    token = re.search(r"mobile-2=(\S+)", printed).group(1)
    digest = re.search(r"^\s+([0-9a-f]{64})$", printed, re.M).group(1)
    assert hashlib.sha256(token.encode()).hexdigest() == digest
    assert len(token) >= 40
    again = re.search(r"mobile-2=(\S+)", _issue("mobile-2")).group(1)
    assert again != token


def test_a_robot_on_the_shared_token_is_told_how_to_get_its_own():
    MobileResourceFactory(name="mobile-1", agent_token_name="default")
    assert "set its agent token name to mobile-1" in _issue("mobile-1")


def test_only_robots_get_agent_tokens():
    FixedResourceFactory(name="node-1")
    with pytest.raises(CommandError, match="no robot named 'node-1'"):
        _issue("node-1")
