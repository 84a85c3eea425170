"""``manage.py testbed_setup``: the real installation's resources, once."""

from __future__ import annotations

import io
import re

import pytest
from django.core.management import CommandError, call_command

from bookings.choices import ResourceKind
from bookings.models import Resource

pytestmark = pytest.mark.django_db


def _setup(*args: str) -> str:
    out = io.StringIO()
    call_command("testbed_setup", *args, stdout=out)
    return out.getvalue()


def test_it_creates_the_mobile_node_and_the_fixed_nodes_once():
    first = _setup("--agent-url", "http://basestation.local:8700")
    assert "25 resource(s) created" in first
    mobile = Resource.objects.get(name="mobile-1")
    assert mobile.kind == ResourceKind.MOBILE
    assert mobile.agent_url == "http://basestation.local:8700"
    assert Resource.objects.filter(kind=ResourceKind.FIXED).count() == 24
    assert Resource.objects.filter(name="node-24").exists()

    # Again, after an admin changed the robot's limit: nothing is created or overwritten.
    Resource.objects.filter(name="mobile-1").update(max_velocity_mps=1.2)
    again = _setup("--agent-url", "http://elsewhere:8700")
    assert "0 resource(s) created" in again
    mobile.refresh_from_db()
    assert (mobile.max_velocity_mps, mobile.agent_url) == (1.2, "http://basestation.local:8700")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--agent-url", "basestation:8700"], "Not an http(s) URL"),
        (["--agent-url", "http://bs:8700", "--fixed-nodes", "0"], "between 1 and 200"),
        (["--agent-url", "http://bs:8700", "--max-velocity-mps", "-1"], "must be positive"),
        (["--agent-url", "http://bs:8700", "--mobile-name", "robot 1"], "robot 1: Enter a valid"),
    ],
)
def test_bad_input_is_refused_and_creates_nothing(args, message):
    with pytest.raises(CommandError, match=re.escape(message)):
        _setup(*args)
    assert not Resource.objects.exists()
