from __future__ import annotations

from datetime import date, datetime, timedelta
from typing import Any

from django.db.models import Prefetch, prefetch_related_objects
from django.shortcuts import get_object_or_404
from django.utils import timezone
from drf_spectacular.utils import OpenApiParameter, extend_schema
from rest_framework import serializers, status
from rest_framework.permissions import IsAdminUser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings import robot, services
from bookings.choices import QuotaPeriod, ReservationState
from bookings.models import (
    Blackout,
    QuotaPolicy,
    Reservation,
    ReservationItem,
    Resource,
    ResourceGroup,
)
from bookings.quotas import quota_summary, quota_violations
from bookings.selectors import (
    blackouts_overlapping,
    items_overlapping,
    reservations_visible,
    resource_free_intervals,
)
from portal.accounts.models import User
from portal.audit.idempotency import idempotent
from portal.audit.services import client_ip
from portal.experiments.selectors import experiments_visible

MAX_RANGE = timedelta(days=62)


def _user(request: Request) -> User:
    user = request.user
    assert isinstance(user, User)
    return user


def _valid(serializer_class: type[serializers.Serializer], data: Any) -> dict[str, Any]:
    serializer = serializer_class(data=data)
    serializer.is_valid(raise_exception=True)
    return dict(serializer.validated_data)


class ResourceOutput(serializers.ModelSerializer):
    groups: serializers.SlugRelatedField[ResourceGroup] = serializers.SlugRelatedField(
        many=True, slug_field="name", read_only=True
    )

    class Meta:
        model = Resource
        fields = [
            "id",
            "name",
            "kind",
            "description",
            "groups",
            "max_velocity_mps",
            "max_accel_mps2",
            "enabled",
            "requires_approval",
        ]


class ResourceListApi(APIView):
    @extend_schema(responses=ResourceOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = Resource.objects.prefetch_related("groups")
        return Response(ResourceOutput(qs, many=True).data)


class RangeQuery(serializers.Serializer):
    start = serializers.DateTimeField()
    end = serializers.DateTimeField()

    def validate(self, attrs: dict[str, Any]) -> dict[str, Any]:
        if attrs["end"] <= attrs["start"]:
            raise serializers.ValidationError({"end": "Must be after start."})
        if attrs["end"] - attrs["start"] > MAX_RANGE:
            raise serializers.ValidationError({"end": "Ask for at most 62 days at a time."})
        return attrs


class AvailabilityApi(APIView):
    @extend_schema(
        parameters=[OpenApiParameter("start", datetime), OpenApiParameter("end", datetime)],
        responses={200: dict},
    )
    def get(self, request: Request, name: str) -> Response:
        resource = get_object_or_404(Resource, name=name)
        query = _valid(RangeQuery, request.query_params)
        free = resource_free_intervals(
            resource=resource, start_at=query["start"], end_at=query["end"]
        )
        return Response(
            {
                "resource": resource.name,
                "start": query["start"],
                "end": query["end"],
                "free": [{"start": s, "end": e} for s, e in free],
            }
        )


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


class BusyOutput(serializers.Serializer):
    """What others see of someone else's reservation: only that the time is taken."""

    resources = serializers.ListField(child=serializers.CharField())
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()
    state = serializers.CharField()


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
        query = _valid(ReservationFilter, request.query_params)
        qs = reservations_visible(user=_user(request))
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
        user = _user(request)
        data = _valid(ReservationInput, request.data)
        owner = data.pop("owner", None) or user
        experiment_id = data.pop("experiment", None)
        experiment = None
        if experiment_id is not None:
            experiment = get_object_or_404(experiments_visible(user=user), pk=experiment_id)
        reservation = services.reservation_create(
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
        return get_object_or_404(reservations_visible(user=_user(request)), pk=pk)

    @extend_schema(responses=ReservationOutput)
    def get(self, request: Request, pk: int) -> Response:
        return Response(ReservationOutput(self._get(request, pk)).data)

    @extend_schema(request=RescheduleInput, responses=ReservationOutput)
    def patch(self, request: Request, pk: int) -> Response:
        data = _valid(RescheduleInput, request.data)
        reservation = services.reservation_reschedule(
            reservation=self._get(request, pk), by=_user(request), ip=client_ip(request), **data
        )
        return Response(
            ReservationOutput(reservations_visible(user=_user(request)).get(pk=reservation.pk)).data
        )

    @extend_schema(request=CancelInput, responses=ReservationOutput)
    def delete(self, request: Request, pk: int) -> Response:
        data = _valid(CancelInput, request.data or {})
        reservation = services.reservation_cancel(
            reservation=self._get(request, pk),
            by=_user(request),
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
        data = _valid(DecisionInput, request.data)
        reservation = services.reservation_decide(
            reservation=get_object_or_404(Reservation, pk=pk),
            by=_user(request),
            ip=client_ip(request),
            **data,
        )
        return Response(ReservationOutput(reservation).data)


class BusyApi(APIView):
    """Every active booking in a range, others' shown only as busy (calendar and scheduler)."""

    @extend_schema(parameters=[RangeQuery], responses=BusyOutput(many=True))
    def get(self, request: Request) -> Response:
        query = _valid(RangeQuery, request.query_params)
        items = items_overlapping(
            resources=Resource.objects.all(), start_at=query["start"], end_at=query["end"]
        ).order_by("start_at")
        busy: dict[int, dict[str, Any]] = {}
        for item in items:
            entry = busy.setdefault(
                item.reservation_id,
                {
                    "resources": [],
                    "start_at": item.start_at,
                    "end_at": item.end_at,
                    "state": item.reservation.state,
                },
            )
            entry["resources"].append(item.resource.name)
        return Response(BusyOutput(list(busy.values()), many=True).data)


class QuotaApi(APIView):
    @extend_schema(responses={200: dict})
    def get(self, request: Request) -> Response:
        return Response({"policies": quota_summary(user=_user(request), now=timezone.now())})


class QuotaCheckInput(serializers.Serializer):
    resources = serializers.SlugRelatedField(
        many=True, slug_field="name", queryset=Resource.objects.all()
    )
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()


class QuotaCheckApi(APIView):
    """Would this booking fit? For live feedback in the booking form; changes nothing."""

    @extend_schema(request=QuotaCheckInput, responses={200: dict})
    def post(self, request: Request) -> Response:
        data = _valid(QuotaCheckInput, request.data)
        user = _user(request)
        clashes = items_overlapping(
            resources=data["resources"], start_at=data["start_at"], end_at=data["end_at"]
        )
        blackouts = blackouts_overlapping(
            resources=data["resources"], start_at=data["start_at"], end_at=data["end_at"]
        )
        problems = quota_violations(
            user=user,
            resources=data["resources"],
            start_at=data["start_at"],
            end_at=data["end_at"],
            now=timezone.now(),
        )
        return Response(
            {
                "fits": not problems and not clashes.exists() and not blackouts.exists(),
                "quota": problems,
                "conflicts": [
                    f"{i.resource.name} is booked {timezone.localtime(i.start_at):%H:%M}–"
                    f"{timezone.localtime(i.end_at):%H:%M}"
                    for i in clashes
                ],
                "blackouts": [b.reason for b in blackouts],
            }
        )


class BlackoutOutput(serializers.ModelSerializer):
    resources: serializers.SlugRelatedField[Resource] = serializers.SlugRelatedField(
        many=True, slug_field="name", read_only=True
    )

    class Meta:
        model = Blackout
        fields = ["id", "resources", "all_resources", "start_at", "end_at", "reason"]


class BlackoutInput(serializers.Serializer):
    resources = serializers.SlugRelatedField(
        many=True, slug_field="name", queryset=Resource.objects.all(), required=False
    )
    all_resources = serializers.BooleanField(default=False)
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()
    reason = serializers.CharField(max_length=200)


class BlackoutListApi(APIView):
    @extend_schema(parameters=[RangeQuery], responses=BlackoutOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = Blackout.objects.prefetch_related("resources")
        if "start" in request.query_params:
            query = _valid(RangeQuery, request.query_params)
            qs = qs.filter(start_at__lt=query["end"], end_at__gt=query["start"])
        return Response(BlackoutOutput(qs[:500], many=True).data)

    @extend_schema(request=BlackoutInput, responses={201: dict})
    def post(self, request: Request) -> Response:
        data = _valid(BlackoutInput, request.data)
        blackout, conflicts = services.blackout_create(
            by=_user(request), ip=client_ip(request), **data
        )
        return Response(
            {
                "blackout": BlackoutOutput(blackout).data,
                "conflicting_reservations": [r.pk for r in conflicts],
            },
            status=status.HTTP_201_CREATED,
        )


class QuotaPolicySerializer(serializers.ModelSerializer):
    user = serializers.SlugRelatedField(
        slug_field="username", queryset=User.objects.all(), required=False, allow_null=True
    )
    resource = serializers.SlugRelatedField(
        slug_field="name", queryset=Resource.objects.all(), required=False, allow_null=True
    )
    resource_group = serializers.SlugRelatedField(
        slug_field="name", queryset=ResourceGroup.objects.all(), required=False, allow_null=True
    )
    period = serializers.ChoiceField(choices=QuotaPeriod.choices, required=False, allow_blank=True)

    class Meta:
        model = QuotaPolicy
        fields = ["id", *services.QUOTA_FIELDS]


class QuotaPolicyListApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(responses=QuotaPolicySerializer(many=True))
    def get(self, request: Request) -> Response:
        return Response(QuotaPolicySerializer(QuotaPolicy.objects.all(), many=True).data)

    @extend_schema(request=QuotaPolicySerializer, responses={201: QuotaPolicySerializer})
    def post(self, request: Request) -> Response:
        data = _valid(QuotaPolicySerializer, request.data)
        policy = services.quota_policy_save(by=_user(request), ip=client_ip(request), **data)
        return Response(QuotaPolicySerializer(policy).data, status=status.HTTP_201_CREATED)


class QuotaPolicyDetailApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=QuotaPolicySerializer, responses=QuotaPolicySerializer)
    def patch(self, request: Request, pk: int) -> Response:
        policy = get_object_or_404(QuotaPolicy, pk=pk)
        serializer = QuotaPolicySerializer(policy, data=request.data, partial=True)
        serializer.is_valid(raise_exception=True)
        policy = services.quota_policy_save(
            by=_user(request), policy=policy, ip=client_ip(request), **serializer.validated_data
        )
        return Response(QuotaPolicySerializer(policy).data)


class RobotDriveInput(serializers.Serializer):
    velocity_mps = serializers.FloatField()
    direction = serializers.ChoiceField(choices=["cw", "ccw"])
    ttl_s = serializers.FloatField(default=1.0)
    force = serializers.BooleanField(default=False)
    reason = serializers.CharField(allow_blank=True, default="")


class ReasonInput(serializers.Serializer):
    reason = serializers.CharField(allow_blank=True, default="")


class ServiceInput(serializers.Serializer):
    enabled = serializers.BooleanField()
    reason = serializers.CharField(allow_blank=True, default="")


def _mobile_named(name: str) -> Resource:
    return get_object_or_404(Resource, name=name)


class RobotStatusApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(responses={200: dict})
    def get(self, request: Request, name: str) -> Response:
        return Response(robot.robot_status(resource=_mobile_named(name)))


class RobotDriveApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=RobotDriveInput, responses={200: dict})
    def post(self, request: Request, name: str) -> Response:
        data = _valid(RobotDriveInput, request.data)
        return Response(
            robot.robot_drive(
                resource=_mobile_named(name), by=_user(request), ip=client_ip(request), **data
            )
        )


class RobotStopApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=ReasonInput, responses={200: dict})
    def post(self, request: Request, name: str) -> Response:
        data = _valid(ReasonInput, request.data or {})
        return Response(
            robot.robot_stop(
                resource=_mobile_named(name), by=_user(request), ip=client_ip(request), **data
            )
        )


class RobotReleaseApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=ReasonInput, responses={200: dict})
    def post(self, request: Request, name: str) -> Response:
        data = _valid(ReasonInput, request.data or {})
        return Response(
            robot.robot_release(
                resource=_mobile_named(name), by=_user(request), ip=client_ip(request), **data
            )
        )


class RobotLogApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(responses={200: dict})
    def get(self, request: Request, name: str, day: str) -> Response:
        try:
            parsed = date.fromisoformat(day)
        except ValueError:
            return Response({"error": "invalid", "detail": "The day is YYYY-MM-DD."}, status=400)
        return Response(
            robot.robot_day_log(resource=_mobile_named(name), by=_user(request), day=parsed)
        )


class ResourceServiceApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=ServiceInput, responses=ResourceOutput)
    def post(self, request: Request, name: str) -> Response:
        data = _valid(ServiceInput, request.data)
        resource = robot.resource_set_service(
            resource=_mobile_named(name), by=_user(request), ip=client_ip(request), **data
        )
        return Response(ResourceOutput(resource).data)
