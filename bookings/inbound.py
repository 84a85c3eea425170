"""The portal's mobile nodes in the testbed scheduler's own vocabulary (inbound leases).

The testbed's tools book fixed nodes with omf_sfa-style lease requests; here they book the
robot the same way, at ``/scheduler/resources/{nodes,leases}``. A lease is a reservation of
a mobile node, owned by the portal user its account names and made by the scheduler's service
account (a user with the ``bookings.lease_inbound`` permission, authenticating with its API
token). Every booking rule applies (overlaps, maintenance, quotas of the account's user,
approval: a booking awaiting approval is a ``pending`` lease); a refusal is answered in the
broker's envelope ``{"exception": {"code", "reason"}}``. A lease holds the robot without a
program: it stands still unless a run is booked with it in the portal. Only leases made here
can be moved or cancelled here; the others are listed, so the scheduler sees the robot busy.

This module holds the vocabulary (parsing, documents, the envelope, the base view) and the
nodes' view. The leases' view lives in the runs layer (``portal/runs/apis/leases.py``): moving
or cancelling a lease moves or withdraws the run booked with it, through the one service that
changes a booking and its run together, which bookings may not import.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from django.db.models import QuerySet
from drf_spectacular.utils import extend_schema
from rest_framework import exceptions
from rest_framework.permissions import BasePermission
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.choices import BookedVia, ReservationState, ResourceKind
from bookings.models import Reservation, Resource
from bookings.rules import QuotaExceeded
from core.accounts.models import User
from core.accounts.tokens import CachedTokenAuthentication
from core.errors import Conflict, DomainError, NotAllowed

DOMAIN = "amazing"
DEFAULT_STATUSES = ("pending", "accepted", "active")
STATUSES = ("pending", "accepted", "active", "past", "cancelled")
MAX_LEASES = 1000


class InboundError(Exception):
    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason)
        self.code = code
        self.reason = reason


def _envelope(code: int, reason: str) -> Response:
    return Response({"exception": {"code": code, "reason": reason}}, status=code)


def lease_answer(inner: dict[str, Any]) -> Response:
    return Response({"resource_response": {**inner, "about": "/resources/leases"}})


def _wire(value: datetime, *, up: bool = False) -> str:
    """Whole seconds in UTC; an end rounds up so the lease covers the booking."""
    seconds = value.timestamp()
    seconds = math.ceil(seconds) if up else math.floor(seconds)
    return datetime.fromtimestamp(seconds, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _urn(kind: str, name: str) -> str:
    return f"urn:publicid:IDN+{DOMAIN}+{kind}+{name}"


def node_uuid(resource: Resource) -> str:
    return str(uuid.uuid5(uuid.NAMESPACE_URL, _urn("node", resource.name)))


def _node_doc(resource: Resource) -> dict[str, Any]:
    return {
        "uuid": node_uuid(resource),
        "urn": _urn("node", resource.name),
        "name": resource.name,
        "resource_type": "node",
        "domain": DOMAIN,
        "available": resource.in_service,
        "exclusive": True,
    }


def lease_status(reservation: Reservation, now: datetime) -> str:
    if reservation.state in (ReservationState.CANCELLED, ReservationState.REJECTED):
        return "cancelled"
    if reservation.state == ReservationState.REQUESTED:
        return "pending" if reservation.end_at > now else "cancelled"
    if reservation.end_at <= now or reservation.state == ReservationState.COMPLETED:
        return "past"
    return "active" if reservation.start_at <= now else "accepted"


def lease_doc(reservation: Reservation, now: datetime) -> dict[str, Any]:
    mobiles = [item.resource for item in reservation.items.all() if item.resource.is_mobile]
    owner = reservation.owner.get_username()
    return {
        "uuid": str(reservation.public_id),
        "urn": _urn("lease", str(reservation.public_id)),
        "name": reservation.title or f"reservation-{reservation.pk}",
        "resource_type": "lease",
        "valid_from": _wire(reservation.start_at),
        "valid_until": _wire(reservation.end_at, up=True),
        "status": lease_status(reservation, now),
        "account": {"name": owner, "urn": _urn("account", owner), "resource_type": "account"},
        "components": [_node_doc(r) for r in mobiles],
    }


def _mobiles() -> QuerySet[Resource]:
    return Resource.objects.filter(kind=ResourceKind.MOBILE).order_by("name")


def leases_of_mobiles() -> QuerySet[Reservation]:
    return (
        Reservation.objects.filter(items__resource__kind=ResourceKind.MOBILE)
        .select_related("owner")
        .prefetch_related("items__resource")
        .distinct()
        .order_by("start_at")
    )


# --- parsing ----------------------------------------------------------------------------


def body_object(data: Any) -> Mapping[str, Any]:
    if not isinstance(data, Mapping):
        raise InboundError(400, "The body must be a JSON object.")
    return data


def body_text(data: Mapping[str, Any], key: str) -> str:
    value = data.get(key)
    if not isinstance(value, str) or not value.strip() or len(value) > 200:
        raise InboundError(400, f"'{key}' must be a non-empty string of at most 200 characters.")
    return value.strip()


def body_time(data: Mapping[str, Any], key: str) -> datetime:
    value = data.get(key)
    if not isinstance(value, str):
        raise InboundError(400, f"'{key}' must be a time such as 2026-12-01T10:00:00Z.")
    try:
        parsed = datetime.fromisoformat(value)
    except ValueError:
        raise InboundError(400, f"'{key}' is not a time such as 2026-12-01T10:00:00Z.") from None
    if parsed.tzinfo is None:
        raise InboundError(400, f"'{key}' needs a time zone (Z for UTC).")
    return parsed.astimezone(UTC)


def body_components(data: Mapping[str, Any]) -> list[Resource]:
    raw = data.get("components")
    if not isinstance(raw, list) or not raw:
        raise InboundError(400, "'components' must list the nodes to lease.")
    mobiles = list(_mobiles())
    index: dict[str, Resource] = {}
    for r in mobiles:
        index.update({r.name: r, node_uuid(r): r, _urn("node", r.name): r})
    chosen: list[Resource] = []
    for item in raw:
        keys = [item] if isinstance(item, str) else []
        if isinstance(item, Mapping):
            keys = [str(item[k]) for k in ("uuid", "name", "urn") if k in item]
        found = next((index[k] for k in keys if k in index), None)
        if found is None:
            names = ", ".join(r.name for r in mobiles) or "none"
            raise InboundError(
                404, f"No resources matching the request: {item!r} (this portal leases {names})."
            )
        if found not in chosen:
            chosen.append(found)
    return chosen


def body_account(data: Mapping[str, Any]) -> User:
    account = data.get("account_attributes") or data.get("account")
    name = account.get("name") if isinstance(account, Mapping) else None
    if not isinstance(name, str) or not name:
        raise InboundError(400, "Name the account the lease is for (account_attributes.name).")
    user = User.objects.filter(username=name, is_active=True).first()
    if user is None:
        raise InboundError(404, f"No portal account named '{name}'.")
    return user


def lease_find(data: Mapping[str, Any]) -> Reservation:
    """The lease a PUT or DELETE names, by uuid or else by name; only leases made here."""
    leases = leases_of_mobiles()
    found: Reservation | None = None
    if isinstance(data.get("uuid"), str):
        try:
            found = leases.filter(public_id=uuid.UUID(data["uuid"])).first()
        except ValueError:
            found = None
    elif isinstance(data.get("name"), str):
        found = leases.filter(title=data["name"]).order_by("-start_at").first()
    else:
        raise InboundError(400, "Name the lease by uuid (or name).")
    if found is None:
        raise InboundError(404, f"Unknown Lease with descr '{dict(data)}'.")
    if found.booked_via != BookedVia.SCHEDULER:
        raise InboundError(403, "This booking was made in the portal; change it there.")
    return found


# --- views ------------------------------------------------------------------------------


class LeasesAllowed(BasePermission):
    def has_permission(self, request: Request, view: Any) -> bool:
        user = request.user
        return bool(user and user.is_authenticated and user.has_perm("bookings.lease_inbound"))


def _domain_reason(exc: DomainError, resources: list[Resource]) -> tuple[int, str]:
    if isinstance(exc, QuotaExceeded):
        return 403, f"Quota: {exc.message}"
    if isinstance(exc, Conflict):
        names = ", ".join(r.name for r in resources) or "the robot"
        return 409, f"Reservation for the resource '{names}' failed: {exc.message}"
    if isinstance(exc, NotAllowed):
        return 403, exc.message
    return exc.http_status if exc.http_status >= 500 else 400, exc.message


@extend_schema(exclude=True)
class InboundApi(APIView):
    """Base: token authentication, the service account's permission, the broker's envelope."""

    authentication_classes = [CachedTokenAuthentication]
    permission_classes = [LeasesAllowed]
    # The resources a request is about, to name them in a conflict's reason.
    _resources: list[Resource] = []

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, InboundError):
            return _envelope(exc.code, exc.reason)
        if isinstance(exc, DomainError):
            return _envelope(*_domain_reason(exc, getattr(self, "_resources", [])))
        if isinstance(exc, exceptions.NotAuthenticated | exceptions.AuthenticationFailed):
            response = _envelope(401, "Missing or invalid credentials.")
            response["WWW-Authenticate"] = "Token"
            return response
        if isinstance(exc, exceptions.PermissionDenied):
            return _envelope(403, "This account may not lease the portal's nodes.")
        if isinstance(exc, exceptions.APIException):
            return _envelope(exc.status_code, str(exc.detail))
        raise exc


class InboundNodesApi(InboundApi):
    def get(self, request: Request) -> Response:
        docs = [_node_doc(r) for r in _mobiles()]
        name = request.query_params.get("name")
        if name:
            docs = [d for d in docs if d["name"] == name]
            if not docs:
                raise InboundError(404, "No resources matching the request.")
            return Response(
                {"resource_response": {"resource": docs[0], "about": "/resources/nodes"}}
            )
        return Response({"resource_response": {"resources": docs, "about": "/resources/nodes"}})
