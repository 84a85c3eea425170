"""The testbed scheduler's leases of the portal's mobile nodes (``/scheduler/resources/leases``).

The vocabulary (parsing, lease documents, the broker's envelope, authentication) is the
bookings layer's (``bookings/inbound.py``); this view lives with runs because a lease may hold
a run (an experiment attached to it in the portal), and a lease moved or cancelled must move
or withdraw that run with it. It changes bookings only through
``portal/runs/services/reservations.py``, as every other door does.
"""

from __future__ import annotations

from django.utils import timezone
from drf_spectacular.utils import extend_schema
from rest_framework.request import Request
from rest_framework.response import Response

from bookings.choices import BookedVia, Channel
from bookings.inbound import (
    DEFAULT_STATUSES,
    MAX_LEASES,
    STATUSES,
    InboundApi,
    InboundError,
    body_account,
    body_components,
    body_object,
    body_text,
    body_time,
    lease_answer,
    lease_doc,
    lease_find,
    lease_status,
    leases_of_mobiles,
)
from bookings.rules import ProgramRefused
from core.api import request_user
from core.audit.services import client_ip
from portal.runs.services.reservations import (
    reservation_cancel,
    reservation_create,
    reservation_reschedule,
)


@extend_schema(exclude=True)
class InboundLeasesApi(InboundApi):
    def get(self, request: Request) -> Response:
        raw = request.query_params.get("status")
        wanted = tuple(s.strip() for s in raw.split(",")) if raw else DEFAULT_STATUSES
        unknown = [s for s in wanted if s not in STATUSES]
        if unknown:
            raise InboundError(
                400, f"Unknown status {', '.join(unknown)}; use {', '.join(STATUSES)}."
            )
        now = timezone.now()
        leases = leases_of_mobiles()
        if "past" not in wanted and "cancelled" not in wanted:
            leases = leases.filter(end_at__gt=now)
        docs = [
            d for d in (lease_doc(r, now) for r in leases[:MAX_LEASES]) if d["status"] in wanted
        ]
        return lease_answer({"resources": docs})

    def post(self, request: Request) -> Response:
        data = body_object(request.data)
        name = body_text(data, "name")
        start_at, end_at = body_time(data, "valid_from"), body_time(data, "valid_until")
        self._resources = body_components(data)
        reservation = reservation_create(
            owner=body_account(data),
            by=request_user(request),
            resources=self._resources,
            start_at=start_at,
            end_at=end_at,
            title=name,
            ip=client_ip(request),
            booked_via=BookedVia.SCHEDULER,
            via=Channel.LEASE_API,
        )
        return lease_answer({"resource": lease_doc(reservation, timezone.now())})

    def put(self, request: Request) -> Response:
        data = body_object(request.data)
        found = lease_find(data)
        self._resources = [i.resource for i in found.items.all()]
        start_at, end_at = body_time(data, "valid_from"), body_time(data, "valid_until")
        try:
            moved = reservation_reschedule(
                reservation=found,
                by=request_user(request),
                start_at=start_at,
                end_at=end_at,
                ip=client_ip(request),
                via=Channel.LEASE_API,
            )
        except ProgramRefused as exc:
            # The lease holds a run whose program the new window (or the robot) no longer
            # takes: the lease conflicts with what was booked on it. Nothing moved.
            raise InboundError(
                409,
                f"The lease '{found.title}' holds an experiment that the new window does not "
                f"take: {exc.message} Nothing was changed.",
            ) from exc
        return lease_answer(
            {"resource": lease_doc(leases_of_mobiles().get(pk=moved.pk), timezone.now())}
        )

    def delete(self, request: Request) -> Response:
        data = body_object(request.data)
        found = lease_find(data)
        if lease_status(found, timezone.now()) not in ("past", "cancelled"):
            # Its run, if one was attached, is withdrawn with it.
            reservation_cancel(
                reservation=found,
                by=request_user(request),
                reason="cancelled by the scheduler",
                ip=client_ip(request),
                via=Channel.LEASE_API,
            )
        return lease_answer(
            {"resource": lease_doc(leases_of_mobiles().get(pk=found.pk), timezone.now())}
        )
