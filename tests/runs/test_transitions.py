"""The run state machine is one table, enforced by ``run_transition`` and shown in the README."""

from __future__ import annotations

import re
from datetime import timedelta
from pathlib import Path

import pytest
from django.contrib.admin.sites import site
from django.test import RequestFactory
from django.utils import timezone

from core.audit.models import AuditEvent
from core.errors import Conflict
from portal.runs.admin import RunAdmin
from portal.runs.models import Run, RunEvent
from portal.runs.services.reservations import reservation_create
from portal.runs.services.transitions import (
    TransitionNotAllowed,
    run_give_up,
    run_transition,
)
from portal.runs.states import TRANSITIONS, Cause, RunState

pytestmark = pytest.mark.django_db

README = Path(__file__).resolve().parents[2] / "README.md"


@pytest.fixture
def run(owner, mobile, experiment) -> Run:
    start = timezone.now() + timedelta(hours=1)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=experiment,
    )
    return Run.objects.get(reservation=reservation)


def test_the_readme_shows_the_table():
    text = README.read_text()
    block = text.split("<!-- run-transitions")[1].split("<!-- /run-transitions -->")[0]
    rows = set()
    for line in block.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0] not in ("from", "---"):
            from_state = "" if cells[0] == "(booked)" else cells[0]
            rows.add((from_state, cells[1], frozenset(re.split(r",\s*", cells[2]))))
    table = {(a, b, frozenset(c.value for c in causes)) for (a, b), causes in TRANSITIONS.items()}
    assert rows == table


def test_every_state_is_reachable_and_every_end_is_final():
    reached = {to for (_, to) in TRANSITIONS}
    assert reached == set(RunState.values)
    ends = {RunState.COMPLETED, RunState.CANCELLED, RunState.FAILED, RunState.INTERRUPTED}
    assert not [t for t in TRANSITIONS if t[0] in ends]


def test_a_change_outside_the_table_is_refused_and_changes_nothing(run):
    with pytest.raises(TransitionNotAllowed):
        run_transition(
            run_id=run.pk,
            to_state=RunState.COMPLETED,
            cause=Cause.DISPATCH,
            from_states=[RunState.SCHEDULED],
        )
    with pytest.raises(TransitionNotAllowed):
        run_transition(
            run_id=run.pk,
            to_state=RunState.STAGED,
            cause=Cause.BOOKING,
            from_states=[RunState.SCHEDULED],
        )
    run.refresh_from_db()
    assert run.state == RunState.SCHEDULED
    assert list(run.events.values_list("to_state", flat=True)) == [RunState.SCHEDULED]


def test_each_change_records_when_why_cause_and_who(run, owner):
    assert run_transition(
        run_id=run.pk, to_state=RunState.STAGED, cause=Cause.DISPATCH, reason="staged on x"
    )
    # The same step again is no change (a duplicated task).
    assert not run_transition(run_id=run.pk, to_state=RunState.STAGED, cause=Cause.DISPATCH)
    event = RunEvent.objects.filter(run=run).last()
    assert (event.from_state, event.to_state, event.cause, event.reason, event.by) == (
        RunState.SCHEDULED,
        RunState.STAGED,
        Cause.DISPATCH,
        "staged on x",
        None,
    )
    first = RunEvent.objects.filter(run=run).first()
    assert (first.cause, first.by) == (Cause.BOOKING, owner)


def test_an_admin_gives_up_a_scheduled_run_with_a_reason_audited(run, admin_user):
    run_give_up(run=run, by=admin_user, reason="robot away for repair")
    run.refresh_from_db()
    assert run.state == RunState.FAILED
    event = run.events.last()
    assert (event.cause, event.by) == (Cause.ADMIN, admin_user)
    assert AuditEvent.objects.filter(action="run.give_up", reason="robot away for repair").exists()


def test_an_admin_cannot_give_up_a_running_run(run, admin_user):
    run_transition(run_id=run.pk, to_state=RunState.STAGED, cause=Cause.DISPATCH)
    run_transition(run_id=run.pk, to_state=RunState.RUNNING, cause=Cause.DISPATCH)
    with pytest.raises(Conflict, match="cancel the booking"):
        run_give_up(run=run, by=admin_user, reason="stop it")
    run.refresh_from_db()
    assert run.state == RunState.RUNNING


def test_the_admin_page_keeps_state_read_only_and_acts_through_named_actions(run, admin_user):
    model_admin = RunAdmin(Run, site)
    request = RequestFactory().post("/", {"reason": "robot away"})
    request.user = admin_user
    assert "state" in model_admin.get_readonly_fields(request, run)
    assert not model_admin.has_add_permission(request)
    assert not model_admin.has_delete_permission(request, run)
    messages: list[str] = []
    model_admin.message_user = lambda request, message, level=None: messages.append(message)  # type: ignore[method-assign]
    model_admin.give_up(request, Run.objects.filter(pk=run.pk))
    run.refresh_from_db()
    assert run.state == RunState.FAILED, messages
    blank = RequestFactory().post("/", {"reason": " "})
    blank.user = admin_user
    model_admin.cancel_booking(blank, Run.objects.filter(pk=run.pk))
    assert messages[-1] == "Give a reason for the action."
