"""Reservations through the API: booking, moving, cancelling, deciding, checking.

They live with runs because a booking of a mobile node is a reservation and its run, changed
together (``portal/runs/services/booking.py``).
"""

from __future__ import annotations

from typing import Any

from django.db.models import Prefetch, prefetch_related_objects
from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.permissions import IsAdminUser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.choices import ReservationState
from bookings.models import Reservation, ReservationItem, Resource
from portal.accounts.models import User
from portal.api import request_user, valid_input
from portal.audit.idempotency import idempotent
from portal.audit.services import client_ip
from portal.experiments.models import Experiment
from portal.experiments.selectors import experiments_visible
from portal.runs.selectors import reservations_with_runs_visible
from portal.runs.services import booking


def _experiment(request: Request, experiment_id: int | None) -> Experiment | None:
    if experiment_id is None:
        return None
    return get_object_or_404(experiments_visible(user=request_user(request)), pk=experiment_id)


class ReservationOutput(serializers.ModelSerializer):
    resources = serializers.SerializerMethodField()
    owner = serializers.CharField(source="owner.username")
    run = serializers.SerializerMethodField()

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

    def get_run(self, reservation: Reservation) -> dict[str, Any] | None:
        if not any(item.resource.is_mobile for item in reservation.items.all()):
            return None  # only a mobile node runs an experiment: no need to look
        run = getattr(reservation, "run", None)
        return {"id": run.pk, "state": run.state} if run is not None else None


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
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()
    experiment = serializers.IntegerField(required=False, allow_null=True)
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
    start = serializers.DateTimeField(required=False)
    end = serializers.DateTimeField(required=False)
    resource = serializers.CharField(required=False)
    owner = serializers.CharField(required=False)
    state = serializers.ChoiceField(choices=ReservationState.choices, required=False)


class ReservationListApi(APIView):
    @extend_schema(parameters=[ReservationFilter], responses=ReservationOutput(many=True))
    def get(self, request: Request) -> Response:
        query = valid_input(ReservationFilter, request.query_params)
        qs = reservations_with_runs_visible(user=request_user(request))
        if "start" in query:
            qs = qs.filter(end_at__gt=query["start"])
        if "end" in query:
            qs = qs.filter(start_at__lt=query["end"])
        if "resource" in query:
            qs = qs.filter(items__resource__name=query["resource"])
        if "owner" in query:
            qs = qs.filter(owner__username=query["owner"])
        if "state" in query:
            qs = qs.filter(state=query["state"])
        return Response(ReservationOutput(qs.order_by("start_at")[:500], many=True).data)

    @extend_schema(request=ReservationInput, responses={201: ReservationOutput})
    @idempotent
    def post(self, request: Request) -> Response:
        user = request_user(request)
        data = valid_input(ReservationInput, request.data)
        owner = data.pop("owner", None) or user
        experiment = _experiment(request, data.pop("experiment", None))
        reservation = booking.booking_create(
            owner=owner, by=user, experiment=experiment, ip=client_ip(request), **data
        )
        prefetch_related_objects(
            [reservation], Prefetch("items", ReservationItem.objects.select_related("resource"))
        )
        return Response(ReservationOutput(reservation).data, status=status.HTTP_201_CREATED)


class RescheduleInput(serializers.Serializer):
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()


class CancelInput(serializers.Serializer):
    reason = serializers.CharField(required=False, allow_blank=True, default="")


class ReservationDetailApi(APIView):
    def _get(self, request: Request, pk: int) -> Reservation:
        return get_object_or_404(reservations_with_runs_visible(user=request_user(request)), pk=pk)

    @extend_schema(responses=ReservationOutput)
    def get(self, request: Request, pk: int) -> Response:
        return Response(ReservationOutput(self._get(request, pk)).data)

    @extend_schema(request=RescheduleInput, responses=ReservationOutput)
    def patch(self, request: Request, pk: int) -> Response:
        data = valid_input(RescheduleInput, request.data)
        reservation = booking.booking_reschedule(
            reservation=self._get(request, pk),
            by=request_user(request),
            ip=client_ip(request),
            **data,
        )
        return Response(
            ReservationOutput(
                reservations_with_runs_visible(user=request_user(request)).get(pk=reservation.pk)
            ).data
        )

    @extend_schema(request=CancelInput, responses=ReservationOutput)
    def delete(self, request: Request, pk: int) -> Response:
        data = valid_input(CancelInput, request.data or {})
        reservation = booking.booking_cancel(
            reservation=self._get(request, pk),
            by=request_user(request),
            reason=data["reason"],
            ip=client_ip(request),
        )
        return Response(ReservationOutput(reservation).data)


class DecisionInput(serializers.Serializer):
    approve = serializers.BooleanField()
    reason = serializers.CharField(required=False, allow_blank=True, default="")


class ReservationDecisionApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=DecisionInput, responses=ReservationOutput)
    def post(self, request: Request, pk: int) -> Response:
        data = valid_input(DecisionInput, request.data)
        reservation = booking.booking_decide(
            reservation=get_object_or_404(Reservation, pk=pk),
            by=request_user(request),
            ip=client_ip(request),
            **data,
        )
        return Response(ReservationOutput(reservation).data)


class BookingCheckInput(serializers.Serializer):
    resources = serializers.SlugRelatedField(
        many=True, slug_field="name", queryset=Resource.objects.all()
    )
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()
    experiment = serializers.IntegerField(required=False, allow_null=True)


class ProblemOutput(serializers.Serializer):
    code = serializers.ChoiceField(
        choices=["window", "out_of_service", "program", "blackout", "booked", "quota"]
    )
    field = serializers.CharField()
    message = serializers.CharField()


class BookingCheckOutput(serializers.Serializer):
    fits = serializers.BooleanField()
    problems = ProblemOutput(many=True)
    # The same problems by kind, for clients written before ``problems``.
    quota = serializers.ListField(child=serializers.CharField())
    conflicts = serializers.ListField(child=serializers.CharField())
    blackouts = serializers.ListField(child=serializers.CharField())


class BookingCheckApi(APIView):
    """Would this booking be made? Every reason it would not; changes nothing.

    The rules are the ones booking applies (``bookings.rules.booking_problems``).
    """

    @extend_schema(request=BookingCheckInput, responses=BookingCheckOutput)
    def post(self, request: Request) -> Response:
        data = valid_input(BookingCheckInput, request.data)
        problems = booking.booking_check(
            owner=request_user(request),
            resources=data["resources"],
            start_at=data["start_at"],
            end_at=data["end_at"],
            experiment=_experiment(request, data.get("experiment")),
        )
        quota = [m for p in problems if p.code == "quota" for m in p.messages]
        return Response(
            {
                "fits": not problems,
                "problems": [p.as_json() for p in problems],
                "quota": quota,
                "conflicts": [p.message for p in problems if p.code == "booked"],
                "blackouts": [p.message for p in problems if p.code == "blackout"],
            }
        )
