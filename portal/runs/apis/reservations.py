"""Reservations through the API: booking, moving, cancelling, deciding, checking.

They live with runs because a booking of a mobile node is a reservation and its run, changed
together (``portal/runs/services/reservations.py``).
"""

from __future__ import annotations

from typing import Any

from django.http import HttpResponse
from django.shortcuts import get_object_or_404
from django.urls import reverse
from django.utils.encoding import smart_str
from drf_spectacular.utils import extend_schema, extend_schema_field
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.choices import Channel, ReservationState, ResourceKind
from bookings.models import Reservation, ReservationItem, Resource, own_bookings_generations
from bookings.rules import PROBLEM_CODES
from bookings.selectors import resources_by_name
from core.accounts.models import User
from core.accounts.permissions import StaffVerified
from core.api import (
    DateTimeInput,
    Pagination,
    cached_json,
    paginated_data,
    request_user,
    valid_input,
    valid_query,
)
from core.audit.idempotency import idempotent
from core.audit.services import client_ip
from core.openapi import errors
from portal.experiments.models import Experiment
from portal.experiments.selectors import experiments_visible
from portal.runs.models import RUNS
from portal.runs.selectors import (
    LISTED_COLUMNS,
    reservation_resources,
    reservations_listed,
    reservations_with_runs_visible,
    runs_visible,
)
from portal.runs.services import reservations as with_run
from portal.runs.states import RunState

BOOKING_CONFLICT = (
    "The slot is taken, in a maintenance window or over a quota (`quota_exceeded`), or the "
    "reservation is past the state this needs."
)
SCHEDULER_DOWN = "The testbed's scheduler, which books the fixed nodes, did not answer."
SCHEDULER_REFUSED = (
    "The testbed's scheduler answered but would not lease (`scheduler_refused`: credentials, "
    "configuration); nothing was booked."
)


# The header the pages' scripts ("page") and the ``amazing`` command ("cli") send, so that the
# audit log says through which door a booking changed; anything else is the REST API itself.
CLIENT_HEADER = "X-Amazing-Client"
DOORS = {"page": Channel.WEB, "cli": Channel.CLI}


def request_door(request: Request) -> Channel:
    """The door a request to the REST API came through, as the client says (for the audit)."""
    return DOORS.get(request.headers.get(CLIENT_HEADER, ""), Channel.API)


def _experiment(request: Request, experiment_id: int | None) -> Experiment | None:
    if experiment_id is None:
        return None
    return get_object_or_404(experiments_visible(user=request_user(request)), pk=experiment_id)


class RunRefOutput(serializers.Serializer):
    id = serializers.IntegerField()
    state = serializers.ChoiceField(choices=RunState.choices)


class ReservationOutput(serializers.ModelSerializer):
    resources = serializers.SerializerMethodField()
    owner = serializers.CharField(source="owner.username")
    run = serializers.SerializerMethodField(
        help_text="The run of the experiment on a mobile node; null for fixed nodes only."
    )

    class Meta:
        model = Reservation
        fields = [
            "id",
            "resources",
            "owner",
            "title",
            "start_at",
            "end_at",
            "state",
            "run",
            "override_reason",
            "decision_reason",
            "cancel_reason",
            "conflict",
            "created_at",
        ]

    def get_resources(self, reservation: Reservation) -> list[str]:
        return [item.resource.name for item in reservation.items.all()]

    @extend_schema_field(RunRefOutput(allow_null=True))
    def get_run(self, reservation: Reservation) -> dict[str, Any] | None:
        if not any(item.resource.is_mobile for item in reservation.items.all()):
            return None  # only a mobile node runs an experiment: no need to look
        run = getattr(reservation, "run", None)
        return {"id": run.pk, "state": run.state} if run is not None else None


def reservations_represented(page: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``ReservationOutput``'s representation of rows read as ``.values(*LISTED_COLUMNS)``,
    without a model instance or a serializer per row: the same keys in the same order, the same
    values (a test compares the two)."""
    resources = reservation_resources([row["id"] for row in page])
    time = serializers.DateTimeField().to_representation
    represented = []
    for row in page:
        items = resources[row["id"]]
        # As ``ReservationOutput.get_run``: only a mobile node runs an experiment.
        mobile = any(kind == ResourceKind.MOBILE for _, kind in items)
        run_id = row["run__id"]
        represented.append(
            {
                "id": row["id"],
                "resources": [name for name, _ in items],
                "owner": row["owner__username"],
                "title": row["title"],
                "start_at": time(row["start_at"]),
                "end_at": time(row["end_at"]),
                "state": row["state"],
                "run": (
                    {"id": run_id, "state": row["run__state"]}
                    if mobile and run_id is not None
                    else None
                ),
                "override_reason": row["override_reason"],
                "decision_reason": row["decision_reason"],
                "cancel_reason": row["cancel_reason"],
                "conflict": row["conflict"],
                "created_at": time(row["created_at"]),
            }
        )
    return represented


class ReservationInput(serializers.Serializer):
    resources = serializers.SlugRelatedField(
        many=True, slug_field="name", queryset=Resource.objects.all(), required=False
    )
    resource = serializers.SlugRelatedField(
        slug_field="name",
        queryset=Resource.objects.all(),
        required=False,
        help_text="Shorthand for a single resource.",
    )
    start_at = DateTimeInput(help_text="In the future.")
    end_at = DateTimeInput(help_text="After start_at, within the longest reservation.")
    experiment = serializers.IntegerField(
        required=False,
        allow_null=True,
        help_text="The experiment a mobile node runs (needed when booking one).",
    )
    title = serializers.CharField(max_length=200, required=False, allow_blank=True)
    owner = serializers.SlugRelatedField(
        slug_field="username",
        queryset=User.objects.all(),
        required=False,
        help_text="Admins only: book for this user.",
    )
    override_reason = serializers.CharField(required=False, allow_blank=True)

    def validate(self, attrs: dict[str, Any]) -> dict[str, Any]:
        resources = list(attrs.pop("resources", []))
        if "resource" in attrs:
            resources.append(attrs.pop("resource"))
        if not resources:
            raise serializers.ValidationError({"resources": "Give resources (or resource)."})
        attrs["resources"] = resources
        return attrs


class ReservationFilter(serializers.Serializer):
    start = DateTimeInput(required=False, help_text="Only reservations that end after this.")
    end = DateTimeInput(required=False, help_text="Only reservations that begin before this.")
    resource = serializers.CharField(required=False)
    owner = serializers.CharField(required=False, help_text="Username (admins see everyone's).")
    state = serializers.ChoiceField(choices=ReservationState.choices, required=False)


class ReservationListApi(APIView):
    pagination_class = Pagination

    @extend_schema(parameters=[ReservationFilter], responses=ReservationOutput(many=True))
    def get(self, request: Request) -> HttpResponse | Response:
        user = request_user(request)

        def listed() -> dict[str, Any]:
            query = valid_query(ReservationFilter, request.query_params)
            qs = reservations_listed(user=user).overlapping(query.get("start"), query.get("end"))
            if "resource" in query:
                # A subquery, not a join: a reservation is listed once without DISTINCT.
                qs = qs.filter(
                    pk__in=ReservationItem.objects.filter(resource__name=query["resource"]).values(
                        "reservation_id"
                    )
                )
            if "owner" in query:
                qs = qs.filter(owner__username=query["owner"])
            if "state" in query:
                qs = qs.filter(state=query["state"])
            return paginated_data(
                request=request,
                queryset=qs.order_by("start_at", "pk").values(*LISTED_COLUMNS),
                represent=reservations_represented,
            )

        return cached_json(
            request,
            (*own_bookings_generations(user), RUNS),
            (user.pk, user.is_testbed_admin),
            listed,
        )

    @extend_schema(
        request=ReservationInput,
        responses={
            201: ReservationOutput,
            **errors(
                404,
                409,
                502,
                503,
                e404="The experiment is not found.",
                e409=BOOKING_CONFLICT,
                e502=SCHEDULER_REFUSED,
                e503=SCHEDULER_DOWN,
            ),
        },
    )
    @idempotent
    def post(self, request: Request) -> Response:
        user = request_user(request)
        data = valid_input(ReservationInput, request.data)
        owner = data.pop("owner", None) or user
        experiment = _experiment(request, data.pop("experiment", None))
        # The new booking holds its items and their resources: the answer asks nothing more.
        reservation = with_run.reservation_create(
            owner=owner,
            by=user,
            experiment=experiment,
            ip=client_ip(request),
            via=request_door(request),
            **data,
        )
        return Response(ReservationOutput(reservation).data, status=status.HTTP_201_CREATED)


class RescheduleInput(serializers.Serializer):
    start_at = DateTimeInput(help_text="In the future.")
    end_at = DateTimeInput(help_text="After start_at, within the longest reservation.")


class CancelInput(serializers.Serializer):
    reason = serializers.CharField(
        required=False,
        allow_blank=True,
        default="",
        help_text="Why; required when an admin cancels someone else's reservation.",
    )


class RunAgainApi(APIView):
    """Run again: book the run's program with its limits on its robot, in the first free
    slot of its reservation's length (from `RUN_REPEAT_LEAD_S` on). The new run's
    `repeat_of` is this run."""

    @extend_schema(
        request=None,
        responses={
            201: ReservationOutput,
            **errors(
                404,
                409,
                502,
                503,
                e404="The run is not found.",
                e409="No free slot, or the booking is refused (quota, robot out of service).",
                e502=SCHEDULER_REFUSED,
                e503=SCHEDULER_DOWN,
            ),
        },
    )
    @idempotent
    def post(self, request: Request, pk: int) -> Response:
        user = request_user(request)
        run = get_object_or_404(runs_visible(user=user).select_related("experiment"), pk=pk)
        reservation = with_run.reservation_repeat(
            run=run, by=user, ip=client_ip(request), via=request_door(request)
        )
        return Response(ReservationOutput(reservation).data, status=status.HTTP_201_CREATED)


class ReservationDetailApi(APIView):
    def _get(self, request: Request, pk: int) -> Reservation:
        return get_object_or_404(reservations_with_runs_visible(user=request_user(request)), pk=pk)

    @extend_schema(responses=ReservationOutput)
    def get(self, request: Request, pk: int) -> Response:
        return Response(ReservationOutput(self._get(request, pk)).data)

    @extend_schema(
        request=RescheduleInput,
        responses={
            200: ReservationOutput,
            **errors(
                409,
                502,
                503,
                e409=BOOKING_CONFLICT,
                e502=SCHEDULER_REFUSED,
                e503=SCHEDULER_DOWN,
            ),
        },
    )
    def patch(self, request: Request, pk: int) -> Response:
        current = self._get(request, pk)
        # A field left out keeps its value: moving only the end lengthens or shortens it.
        data = valid_input(RescheduleInput, request.data, partial=True)
        reservation = with_run.reservation_reschedule(
            reservation=current,
            by=request_user(request),
            ip=client_ip(request),
            start_at=data.get("start_at", current.start_at),
            end_at=data.get("end_at", current.end_at),
            via=request_door(request),
        )
        return Response(
            ReservationOutput(
                reservations_with_runs_visible(user=request_user(request)).get(pk=reservation.pk)
            ).data
        )

    @extend_schema(
        parameters=[CancelInput],
        responses={
            200: ReservationOutput,
            **errors(
                400,
                409,
                503,
                e409="The reservation is already over or cancelled.",
                e503=SCHEDULER_DOWN,
            ),
        },
    )
    def delete(self, request: Request, pk: int) -> Response:
        # The reason in the query; a JSON body with it (the pages' older calls) still works.
        if request.data:
            data = valid_input(CancelInput, request.data)
        else:
            data = valid_query(CancelInput, request.query_params)
        reservation = with_run.reservation_cancel(
            reservation=self._get(request, pk),
            by=request_user(request),
            reason=data["reason"],
            ip=client_ip(request),
            via=request_door(request),
        )
        return Response(ReservationOutput(reservation).data)


class DecisionInput(serializers.Serializer):
    approve = serializers.BooleanField()
    reason = serializers.CharField(required=False, allow_blank=True, default="")


class ReservationDecisionApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(
        request=DecisionInput,
        responses={
            200: ReservationOutput,
            **errors(409, e409="The reservation is not awaiting a decision."),
        },
    )
    def post(self, request: Request, pk: int) -> Response:
        data = valid_input(DecisionInput, request.data)
        reservation = with_run.reservation_decide(
            reservation=get_object_or_404(Reservation, pk=pk),
            by=request_user(request),
            ip=client_ip(request),
            via=request_door(request),
            **data,
        )
        return Response(ReservationOutput(reservation).data)


class KeptResourceName(serializers.SlugRelatedField[Resource]):
    """A resource by its name, as ``SlugRelatedField`` finds it (the same schema and errors),
    from the kept map of resources (``resources_by_name``) instead of a query each time."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(slug_field="name", queryset=Resource.objects.all(), **kwargs)

    def to_internal_value(self, data: Any) -> Resource:
        if isinstance(data, bool) or not isinstance(data, str | int | float):
            self.fail("invalid")
        resource = resources_by_name().get(str(data))
        if resource is None:
            self.fail("does_not_exist", slug_name="name", value=smart_str(data))
        return resource


class ReservationCheckInput(serializers.Serializer):
    resources = KeptResourceName(many=True)
    start_at = DateTimeInput()
    end_at = DateTimeInput()
    experiment = serializers.IntegerField(required=False, allow_null=True)


class ProblemOutput(serializers.Serializer):
    code = serializers.ChoiceField(
        choices=PROBLEM_CODES,
        help_text="The kind of problem (`lease`: a lease on the testbed's scheduler); `state` "
        "and `reason` come only from changing a booking, never from the check.",
    )
    field = serializers.CharField(help_text="The input it is about; empty: the whole request.")
    message = serializers.CharField()


class ReservationCheckOutput(serializers.Serializer):
    fits = serializers.BooleanField()
    problems = ProblemOutput(many=True)
    needs_approval = serializers.BooleanField(
        help_text="Booked as it is, it would wait for an admin's approval."
    )
    leases_from = serializers.ChoiceField(
        choices=["scheduler", "mirror"],
        allow_null=True,
        help_text="Where the testbed scheduler's leases were read: `scheduler` (asked now, as "
        "booking asks it), `mirror` (it could not be reached: as of its last sync, see "
        "`notice`); null when it was not asked (nothing asked for is the scheduler's).",
    )
    notice = serializers.CharField(help_text="Why the answer may be out of date; usually empty.")
    # The same problems by kind, for clients written before ``problems``.
    quota = serializers.ListField(child=serializers.CharField())
    conflicts = serializers.ListField(child=serializers.CharField())
    blackouts = serializers.ListField(child=serializers.CharField())


CHECK_RESPONSES: dict[Any, Any] = {
    200: ReservationCheckOutput,
    **errors(
        404,
        502,
        e404="The experiment is not found.",
        e502="The testbed's scheduler answered but would not list its leases.",
    ),
}


class ReservationCheckApi(APIView):
    """Would this booking be made? Every reason it would not; changes nothing.

    The rules are the ones booking applies (``bookings/rules.py``), and the testbed's scheduler
    is asked as booking asks it.
    """

    @extend_schema(request=ReservationCheckInput, responses=CHECK_RESPONSES)
    def post(self, request: Request) -> Response:
        data = valid_input(ReservationCheckInput, request.data)
        check = with_run.reservation_check(
            owner=request_user(request),
            resources=data["resources"],
            start_at=data["start_at"],
            end_at=data["end_at"],
            experiment=_experiment(request, data.get("experiment")),
        )
        problems = check.problems
        return Response(
            {
                "fits": check.fits,
                "problems": [p.as_json() for p in problems],
                "needs_approval": check.needs_approval,
                "leases_from": check.leases_from,
                "notice": check.notice,
                "quota": [m for p in problems if p.code == "quota" for m in p.messages],
                "conflicts": [p.message for p in problems if p.code == "booked"],
                "blackouts": [p.message for p in problems if p.code == "blackout"],
            }
        )


class QuotaCheckApi(ReservationCheckApi):
    """The live check's first name, kept for one release: use `POST /api/v1/reservations/check/`."""

    @extend_schema(request=ReservationCheckInput, responses=CHECK_RESPONSES, deprecated=True)
    def post(self, request: Request) -> Response:
        response = super().post(request)
        response["Deprecation"] = "true"
        response["Link"] = f'<{reverse("api-reservations-check")}>; rel="successor-version"'
        return response
