"""Bookings and their runs changed at random through every door, checked after each step.

The doors: the REST API (as itself, as the pages' scripts and as the ``amazing`` command
say they are), the lease API of the testbed scheduler, the Django admin's reservation actions,
the Book page's form and the pages' cancel form. After every step: a scheduled run's booking
is requested or confirmed and holds the run's window; every run's program fits its window; no
two active bookings of the robot overlap; every change is audited with the door it came
through.
"""

from __future__ import annotations

from datetime import UTC, timedelta
from itertools import pairwise
from zoneinfo import ZoneInfo

import pytest
from django.conf import settings as django_settings
from django.contrib import admin
from django.contrib.auth.models import Permission
from django.contrib.messages.storage.cookie import CookieStorage
from django.db import transaction
from django.test import Client, RequestFactory
from django.utils import timezone
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule, run_state_machine_as_test
from rest_framework.test import APIClient

from bookings.choices import RESERVATION_ACTIVE_STATES, ReservationState
from bookings.models import Reservation, ReservationItem
from core.audit.models import AuditEvent
from portal.runs.models import Run
from portal.runs.states import RunState
from tests.conftest import staff_verified
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory, api_token

pytestmark = pytest.mark.django_db

LEASES = "/scheduler/resources/leases"
SLOTS = 6  # ten-minute slots a day ahead: few enough that bookings collide
LENGTHS_S = [20, 60, 600]  # the experiment lasts 40 s: 20 s never fits it
HEADERS = {
    "api": {},
    "web": {"HTTP_X_AMAZING_CLIENT": "page"},
    "cli": {"HTTP_X_AMAZING_CLIENT": "cli"},
}


def _wire(value) -> str:
    return value.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


class BookingDoors(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        # Each example in a savepoint of the test's transaction, rolled back at its end.
        self._atomic = transaction.atomic()
        self._atomic.__enter__()
        self.robot = MobileResourceFactory(requires_approval=True)
        self.owner = UserFactory()
        # Its admin actions are called here, past the admin site's door: marked as that door
        # marks staff whose session passed the second factor.
        self.staff = staff_verified(UserFactory(is_staff=True, is_superuser=True))
        account = UserFactory()
        account.user_permissions.add(Permission.objects.get(codename="lease_inbound"))
        self.scheduler = APIClient()
        self.scheduler.credentials(HTTP_AUTHORIZATION=f"Token {api_token(account)}")
        self.api = APIClient()
        self.api.force_authenticate(self.owner)
        self.pages = Client()
        self.pages.force_login(self.owner)
        self.experiment = ExperimentFactory(
            owner=self.owner,
            segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 40.0}],
        )
        self.base = timezone.now().replace(second=0, microsecond=0) + timedelta(days=1)
        # The doors each booking's changes came through, in order, as the audit should say.
        self.doors: dict[int, list[tuple[str, str]]] = {}

    def teardown(self) -> None:
        transaction.set_rollback(True)
        self._atomic.__exit__(None, None, None)

    def _window(self, slot: int, length_s: int) -> tuple[str, str]:
        start = self.base + timedelta(minutes=10 * slot)
        return _wire(start), _wire(start + timedelta(seconds=length_s))

    def _mine(self):
        return Reservation.objects.filter(items__resource=self.robot).distinct().order_by("pk")

    def _pick(self, index: int) -> Reservation | None:
        mine = list(self._mine())
        return mine[index % len(mine)] if mine else None

    def _done(self, answer, reservation_id: int | None, action: str, door: str) -> None:
        if answer.status_code < 300 and reservation_id is not None:
            self.doors.setdefault(reservation_id, []).append((action, door))

    # --- the doors ----------------------------------------------------------------------

    @rule(
        door=st.sampled_from(list(HEADERS)),
        slot=st.integers(0, SLOTS - 1),
        length_s=st.sampled_from(LENGTHS_S),
    )
    def book_through_the_api(self, door: str, slot: int, length_s: int) -> None:
        start_at, end_at = self._window(slot, length_s)
        body = {
            "resources": [self.robot.name],
            "start_at": start_at,
            "end_at": end_at,
            "experiment": self.experiment.pk,
        }
        answer = self.api.post("/api/v1/reservations/", body, format="json", **HEADERS[door])
        assert answer.status_code in (201, 400, 409), answer.content
        made = answer.json().get("id") if answer.status_code == 201 else None
        self._done(answer, made, "reservation.create", door)

    @rule(
        slot=st.integers(0, SLOTS - 1),
        length_s=st.sampled_from(LENGTHS_S),
        # Mostly with it: the robot is refused without the experiment it will run.
        with_experiment=st.sampled_from([True, True, True, False]),
    )
    def book_on_the_page(self, slot: int, length_s: int, with_experiment: bool) -> None:
        """The Book page's form: times typed as the testbed's wall clock, to the minute."""
        zone = ZoneInfo(django_settings.TIME_ZONE)
        start = (self.base + timedelta(minutes=10 * slot)).astimezone(zone)
        end = start + timedelta(seconds=max(length_s, 60))  # the form takes whole minutes
        form = {
            "resource": self.robot.name,
            "start_at": start.strftime("%Y-%m-%dT%H:%M"),
            "end_at": end.strftime("%Y-%m-%dT%H:%M"),
            "experiment": str(self.experiment.pk) if with_experiment else "",
        }
        before = set(self._mine().values_list("pk", flat=True))
        answer = self.pages.post("/book/", form)
        assert answer.status_code in (200, 302), answer.status_code
        made = set(self._mine().values_list("pk", flat=True)) - before
        assert len(made) == (1 if answer.status_code == 302 else 0), answer.status_code
        self._done(answer, made.pop() if made else None, "reservation.create", "web")

    @rule(slot=st.integers(0, SLOTS - 1), length_s=st.sampled_from(LENGTHS_S))
    def lease(self, slot: int, length_s: int) -> None:
        start_at, end_at = self._window(slot, length_s)
        body = {
            "name": f"lease-{slot}",
            "valid_from": start_at,
            "valid_until": end_at,
            "account_attributes": {"name": self.owner.username},
            "components": [{"name": self.robot.name}],
        }
        answer = self.scheduler.post(LEASES, body, format="json")
        assert answer.status_code in (200, 400, 409), answer.content
        if answer.status_code == 200:
            uuid = answer.json()["resource_response"]["resource"]["uuid"]
            made = Reservation.objects.get(public_id=uuid).pk
            self._done(answer, made, "reservation.create", "lease_api")

    @rule(index=st.integers(0, 50), door=st.sampled_from(list(HEADERS)))
    def attach(self, index: int, door: str) -> None:
        reservation = self._pick(index)
        if reservation is None:
            return
        answer = self.api.post(
            f"/api/v1/reservations/{reservation.pk}/attach/",
            {"experiment": self.experiment.pk},
            format="json",
            **HEADERS[door],
        )
        assert answer.status_code in (201, 400, 409), answer.content
        self._done(answer, reservation.pk, "reservation.attach", door)

    @rule(
        index=st.integers(0, 50),
        slot=st.integers(0, SLOTS - 1),
        length_s=st.sampled_from(LENGTHS_S),
        door=st.sampled_from([*HEADERS, "lease_api"]),
    )
    def move(self, index: int, slot: int, length_s: int, door: str) -> None:
        reservation = self._pick(index)
        if reservation is None:
            return
        start_at, end_at = self._window(slot, length_s)
        if door == "lease_api":
            body = {
                "uuid": str(reservation.public_id),
                "valid_from": start_at,
                "valid_until": end_at,
            }
            answer = self.scheduler.put(LEASES, body, format="json")
        else:
            answer = self.api.patch(
                f"/api/v1/reservations/{reservation.pk}/",
                {"start_at": start_at, "end_at": end_at},
                format="json",
                **HEADERS[door],
            )
        assert answer.status_code in (200, 400, 403, 409), answer.content
        self._done(answer, reservation.pk, "reservation.reschedule", door)

    @rule(index=st.integers(0, 50), door=st.sampled_from([*HEADERS, "lease_api", "page", "admin"]))
    def cancel(self, index: int, door: str) -> None:
        reservation = self._pick(index)
        if reservation is None:
            return
        ok = False
        if door == "lease_api":
            before = reservation.state
            answer = self.scheduler.delete(
                LEASES, {"uuid": str(reservation.public_id)}, format="json"
            )
            assert answer.status_code in (200, 403), answer.content
            reservation.refresh_from_db()
            ok = before != reservation.state
        elif door == "page":
            before = reservation.state
            answer = self.pages.post(
                f"/reservations/{reservation.pk}/cancel/", {"reason": "not needed"}
            )
            assert answer.status_code in (200, 302)
            reservation.refresh_from_db()
            ok = before != reservation.state
            door = "web"
        elif door == "admin":
            before = reservation.state
            self._admin_action("cancel", reservation, reason="robot needed")
            reservation.refresh_from_db()
            ok = before != reservation.state
        else:
            answer = self.api.delete(
                f"/api/v1/reservations/{reservation.pk}/?reason=not+needed", **HEADERS[door]
            )
            assert answer.status_code in (200, 400, 409), answer.content
            ok = answer.status_code == 200
        if ok:
            self.doors.setdefault(reservation.pk, []).append(("reservation.cancel", door))

    @rule(index=st.integers(0, 50), approve=st.booleans())
    def decide_in_the_admin(self, index: int, approve: bool) -> None:
        reservation = self._pick(index)
        if reservation is None:
            return
        before = reservation.state
        self._admin_action("approve" if approve else "reject", reservation, reason="decided")
        reservation.refresh_from_db()
        if before == ReservationState.REQUESTED:
            assert reservation.state != before, "an admin's decision was refused"
        if before != reservation.state:
            action = "reservation.approve" if approve else "reservation.reject"
            self.doors.setdefault(reservation.pk, []).append((action, "admin"))

    def _admin_action(self, name: str, reservation: Reservation, *, reason: str) -> None:
        request = RequestFactory().post("/admin/bookings/reservation/", {"reason": reason})
        request.user = self.staff
        request._messages = CookieStorage(request)  # type: ignore[attr-defined]
        model_admin = admin.site._registry[Reservation]
        getattr(model_admin, name)(request, Reservation.objects.filter(pk=reservation.pk))

    # --- what must hold after every step ------------------------------------------------

    @invariant()
    def a_scheduled_run_is_its_booking_s(self) -> None:
        for run in Run.objects.filter(resource=self.robot).select_related("reservation"):
            booking = run.reservation
            assert (run.start_at, run.end_at) == (booking.start_at, booking.end_at)
            length_s = (booking.end_at - booking.start_at).total_seconds()
            assert sum(s["duration_s"] for s in run.segments) <= length_s
            if run.state == RunState.SCHEDULED:
                assert booking.state in RESERVATION_ACTIVE_STATES, (run, booking.state)
            else:
                assert run.state == RunState.CANCELLED
                assert booking.state not in RESERVATION_ACTIVE_STATES

    @invariant()
    def no_two_active_bookings_of_the_robot_overlap(self) -> None:
        items = list(
            ReservationItem.objects.filter(resource=self.robot, active=True).order_by("start_at")
        )
        for earlier, later in pairwise(items):
            assert earlier.end_at <= later.start_at

    @invariant()
    def every_change_is_audited_with_its_door(self) -> None:
        for reservation_id, doors in self.doors.items():
            rows = AuditEvent.objects.filter(
                target_type="bookings.reservation",
                target_id=str(reservation_id),
                action__in=[a for a, _ in doors] + ["reservation.override"],
            ).order_by("pk")
            seen = [
                (r.action, r.data.get("via")) for r in rows if r.action != "reservation.override"
            ]
            assert seen == doors


def test_every_door_keeps_a_booking_and_its_run_together():
    run_state_machine_as_test(
        BookingDoors,
        settings=settings(
            max_examples=6,
            stateful_step_count=10,
            deadline=None,
            suppress_health_check=[HealthCheck.too_slow],
        ),
    )
