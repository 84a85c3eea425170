"""The OpenAPI description holds: schemathesis against a live portal, as an outside client.

``schemathesis run`` against the real web server on PostgreSQL with production settings
(``PRODUCTION``: DEBUG off, the sign-in limits on), once as an experimenter (every
operation but the token's revocation) and once as an admin (the operations whose answer is
staff's own: ``ADMIN_OPERATIONS``), each with their token, with every check it has, a fixed
seed and a bounded number of examples per operation; it must find nothing. Each
``[[operations]]`` entry names one operation (``include-name``): filters of different kinds in
one entry select what any of them matches.

Checks not run everywhere, and why:

- ``positive_data_acceptance`` is replaced on the operations listed in
  ``tests/api/contract_hooks.py``, with the reason for each: their requests must meet
  conditions JSON Schema cannot state (stored names, one field against another or the clock).
- ``object_level_authorization`` runs in the experimenter's run, with a second experimenter
  as the peer who must not read her objects. An admin may read every object, so the admin's
  run has no peer to compare with and the check does nothing there.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from datetime import timedelta
from pathlib import Path

import pytest
from django.utils import timezone

from bench.stack import REPO, free_port
from portal.runs.services.reservations import reservation_create
from tests.api.contract_hooks import DATA_DEPENDENT
from tests.factories import (
    ExperimentFactory,
    FixedResourceFactory,
    MobileResourceFactory,
    UserFactory,
    api_token,
)
from tests.integration.live import live_portal
from tests.runs.driving import completed_run

pytestmark = [pytest.mark.integration, pytest.mark.long, pytest.mark.django_db(transaction=True)]

SEED = 20261123
# Fuzzed cases per operation (the coverage phase's own cases come on top, as many as the
# schema's boundaries ask for): at 12, this file was the suite's longest on a slow machine.
MAX_EXAMPLES = 6
# One run took 7.5 minutes on a 2-core machine busy with other builds. The test's own limit
# (pytest-timeout) leaves room above schemathesis's for the database set-up and the portal's
# start, so that a slow run fails here, with schemathesis's report, not in the middle of it.
SCHEMATHESIS_TIMEOUT_S = 600
TEST_TIMEOUT_S = SCHEMATHESIS_TIMEOUT_S + 180
SCHEMATHESIS = Path(sys.executable).parent / "schemathesis"
# Whose token each run uses, and the peers object_level_authorization compares.
RUNS = {"experimenter": ("erin", ["erin", "bob"]), "admin": ("ada", [])}
# The admin's run fuzzes the operations whose answer or permission is staff's own: the
# staff-only ones, and those with a staff branch (everyone's rows, no one's events, the fields
# only admins may give, a staff token). Every other operation answers an admin as it answers
# the owner of what it reads, through the same code: the experimenter's run fuzzes all of them.
ADMIN_OPERATIONS = frozenset(
    {
        "GET /api/v1/audit/",
        "POST /api/v1/auth/token/",
        "GET /api/v1/blackouts/",
        "POST /api/v1/blackouts/",
        "GET /api/v1/events/",
        "GET /api/v1/me/",
        "GET /api/v1/quota/",
        "POST /api/v1/quota/check/",
        "GET /api/v1/quota-policies/",
        "POST /api/v1/quota-policies/",
        "PATCH /api/v1/quota-policies/{id}/",
        "GET /api/v1/reservations/",
        "POST /api/v1/reservations/",
        "GET /api/v1/reservations/{id}/",
        "PATCH /api/v1/reservations/{id}/",
        "DELETE /api/v1/reservations/{id}/",
        "POST /api/v1/reservations/{id}/decision/",
        "GET /api/v1/reservations/busy/",
        "POST /api/v1/reservations/check/",
        "GET /api/v1/resources/",
        "GET /api/v1/resources/{name}/robot/",
        "POST /api/v1/resources/{name}/robot/control/",
        "GET /api/v1/resources/{name}/robot/logs/{day}/",
        "POST /api/v1/resources/{name}/robot/release/",
        "POST /api/v1/resources/{name}/robot/stop/",
        "POST /api/v1/resources/{name}/service/",
        "GET /api/v1/runs/",
        "GET /api/v1/runs/{id}/",
        "POST /api/v1/webhooks/",
        "GET /api/v1/queue/",
        "DELETE /api/v1/queue/{id}/",
        "POST /api/v1/queue/pause/",
        "POST /api/v1/queue/resume/",
        "POST /api/v1/queue/{id}/reorder/",
        "GET /api/v1/campaigns/",
        "GET /api/v1/campaigns/{id}/",
        "POST /api/v1/campaigns/{id}/cancel/",
    }
)


# Of those, the ones that answer anyone but staff 403 whatever the request holds.
STAFF_ONLY_OPERATIONS = frozenset(
    {
        "GET /api/v1/audit/",
        "GET /api/v1/quota-policies/",
        "POST /api/v1/quota-policies/",
        "PATCH /api/v1/quota-policies/{id}/",
        "POST /api/v1/resources/{name}/robot/control/",
        "POST /api/v1/resources/{name}/robot/release/",
        "POST /api/v1/resources/{name}/robot/stop/",
        "POST /api/v1/resources/{name}/service/",
        "POST /api/v1/queue/pause/",
        "POST /api/v1/queue/resume/",
        "POST /api/v1/queue/{id}/reorder/",
    }
)
assert STAFF_ONLY_OPERATIONS <= ADMIN_OPERATIONS


# The portal as deployed (DEBUG off), but for plain HTTP on the loopback, where nothing
# terminates TLS, and no access line per request.
PRODUCTION = {
    "DJANGO_DEBUG": "0",
    "DJANGO_SSL_REDIRECT": "0",
    "DJANGO_ALLOWED_HOSTS": "127.0.0.1",
    "ACCESS_LOG": "0",
}


def world(*, agent_url: str) -> dict:
    """What the portal holds while it is fuzzed: users, a robot, nodes, bookings, a run."""
    erin = UserFactory(username="erin")
    bob = UserFactory(username="bob")
    ada = UserFactory(username="ada", is_staff=True, is_superuser=True)
    mobile = MobileResourceFactory(agent_url=agent_url)
    FixedResourceFactory(name="node-01")
    FixedResourceFactory(name="node-02", requires_approval=True)
    run = completed_run(erin, mobile, [(0.5, "cw", 2.0), (0.8, "ccw", 2.0)])
    start = timezone.now() + timedelta(days=3)
    reservation_create(
        owner=erin,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=30),
        experiment=ExperimentFactory(owner=erin),
    )
    tokens = {u.username: api_token(u) for u in (erin, bob, ada)}
    return {"tokens": tokens, "run": run.pk}


def _toml(value: object) -> str:
    return json.dumps(value)  # strings, numbers, booleans and lists of them: as in TOML


def config(world: dict, *, role: str, auth_file: Path) -> str:
    user, peers = RUNS[role]
    lines = [
        f"seed = {SEED}",
        'hooks = "tests.api.contract_hooks"',
        "[generation]",
        f"max-examples = {MAX_EXAMPLES}",
        'database = "none"',
        # Every check, each with its defaults; the exceptions follow per operation.
        "[checks]",
        "enabled = true",
        # A long poll (GET /api/v1/events/, the only operation with a ``wait``) waits up to
        # ``wait`` seconds for an event that a fuzzer never makes: asked without waiting, so
        # that the run does not sleep. The wait itself is held by tests/core/test_events.py (an
        # answer the moment an event commits). A project-wide value: on the operation's own
        # ``[[operations]]`` entry, schemathesis 4.32 did not apply it.
        "[parameters]",
        '"query.wait" = 0',
        "[auth.wfc]",
        f"path = {_toml(str(auth_file))}",
        f"user = {_toml(user)}",
    ]
    if peers:
        lines.append(f"peers = {_toml(peers)}")
    # The stored run's reads go to it, so that its answers' shapes are checked too.
    # One operation each, by its name: an entry's filters of different kinds (a path, a
    # method) select what any of them matches, not what all do.
    for path in ("/", "/samples/", "/samples.csv", "/samples.json", "/analysis/"):
        lines += [
            "[[operations]]",
            f"include-name = {_toml('GET /api/v1/runs/{id}' + path)}",
            "[operations.parameters]",
            f"id = {world['run']}",
        ]
    # Not fuzzed: ``DELETE /api/v1/auth/token/`` revokes the token it is sent with, the one
    # the whole run presents (schemathesis sends its configured credentials whatever an
    # operation's own headers say), and every later case would meet a 401. Its contract is
    # held by tests/portal/test_mfa_and_tokens.py and tests/cli/test_commands.py (``amazing
    # logout`` revokes).
    lines += [
        "[[operations]]",
        'include-name = "DELETE /api/v1/auth/token/"',
        "enabled = false",
    ]
    if role == "admin":
        lines += [
            "[[operations]]",
            f"exclude-name = {_toml(sorted(ADMIN_OPERATIONS))}",
            "enabled = false",
        ]
    else:
        # Staff's own operations refuse an experimenter before reading anything she sends:
        # a few cases check the refusal is documented; the admin's run fuzzes them.
        lines += [
            "[[operations]]",
            f"include-name = {_toml(sorted(STAFF_ONLY_OPERATIONS))}",
            "[operations.generation]",
            "max-examples = 2",
            "[operations.phases.coverage]",
            "enabled = false",
        ]
    for method, path in sorted(DATA_DEPENDENT):
        lines += [
            "[[operations]]",
            f"include-name = {_toml(f'{method} {path}')}",
            "[operations.checks.positive_data_acceptance]",
            "enabled = false",
        ]
    return "\n".join(lines) + "\n"


def auth_document(world: dict) -> dict:
    """The users' tokens in the Web Fuzzing Commons form schemathesis reads."""
    return {
        "auth": [
            {"name": name, "fixedHeaders": [{"name": "Authorization", "value": f"Token {key}"}]}
            for name, key in world["tokens"].items()
        ]
    }


def _text(output: str | bytes | None) -> str:
    return output.decode(errors="replace") if isinstance(output, bytes) else output or ""


def _schemathesis(config_file: Path, url: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            str(SCHEMATHESIS),
            "--config-file",
            str(config_file),
            "--no-color",
            "run",
            f"{url}/api/schema/",
            "--workers",
            "1",
            "--suppress-health-check",
            "all",
        ],
        # Its cache and reports stay out of the checkout.
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=SCHEMATHESIS_TIMEOUT_S,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )


# One test per role, each in its own file (this one and test_contract_admin.py): files are
# what the workers share out, and the two runs are the suite's longest after the soak, so
# two workers run them at once instead of one after the other.
@pytest.mark.timeout(TEST_TIMEOUT_S)
def test_schemathesis_finds_nothing_against_a_live_portal_as_an_experimenter(tmp_path):
    schemathesis_finds_nothing("experimenter", tmp_path)


def schemathesis_finds_nothing(role: str, tmp_path: Path) -> None:
    agent_port = free_port()
    held = world(agent_url=f"http://127.0.0.1:{agent_port}")
    auth_file = tmp_path / "auth.json"
    auth_file.write_text(json.dumps(auth_document(held)))
    config_file = tmp_path / "schemathesis.toml"
    config_file.write_text(config(held, role=role, auth_file=auth_file))
    # The throttles have their own tests; a fuzzer sends far more than any client may.
    with live_portal(
        tmp_path,
        agent_port=agent_port,
        API_THROTTLE_ANON="off",
        API_THROTTLE_USER="off",
        **PRODUCTION,
    ) as portal:
        try:
            result = _schemathesis(config_file, portal.url, tmp_path)
        except subprocess.TimeoutExpired as exc:
            pytest.fail(
                f"schemathesis ran over {SCHEMATHESIS_TIMEOUT_S} s\n"
                f"{_text(exc.stdout)[-20000:]}\n{_text(exc.stderr)[-3000:]}\n{portal.output(80)}"
            )
        logs = portal.output(80)
    report = result.stdout[-20000:] + result.stderr[-3000:]
    assert result.returncode == 0, report + "\n" + logs
    # The admin's run reached each of its operations, and only those (a name not in the
    # schema would silently select nothing).
    if role == "admin":
        assert re.search(rf"Operations:\s+{len(ADMIN_OPERATIONS)} selected / ", report), report
    # Every generated case passed every check (the summary's own count says so).
    assert re.search(r"\n  (\d+) generated, \1 passed", report), report
    # And the cases reached the API's logic: no operation met only 401s (a token revoked under
    # the run, or one never sent), which every check would pass. (Only 403s is right for an
    # experimenter on the admin's operations.)
    assert "401 Unauthorized (" not in result.stdout, report
