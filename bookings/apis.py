from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

from django.http import Http404, HttpResponse
from django.shortcuts import get_object_or_404
from django.utils import timezone
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings import services
from bookings.choices import QuotaPeriod
from bookings.models import (
    CALENDAR_SETUP,
    Blackout,
    QuotaPolicy,
    Resource,
    ResourceGroup,
    availability_generations,
    busy_generations,
    own_bookings_generations,
)
from bookings.quotas import period_bounds, quota_summary
from bookings.selectors import busy_slots, resource_free_intervals
from core.accounts.models import User
from core.accounts.permissions import StaffVerified
from core.api import (
    DateTimeInput,
    GreaterThan,
    Pagination,
    cached_json,
    paginated_response,
    request_user,
    rfc3339_instant,
    valid_input,
    valid_query,
)
from core.audit.services import client_ip

MAX_RANGE = timedelta(days=62)


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
            "hold_reason",
            "held_at",
            "requires_approval",
        ]


class ResourceListApi(APIView):
    """Every resource, the mobile node(s) and the fixed nodes (a short list: not paginated)."""

    @extend_schema(responses=ResourceOutput(many=True))
    def get(self, request: Request) -> HttpResponse | Response:
        return cached_json(
            request,
            (CALENDAR_SETUP,),
            (),
            lambda: ResourceOutput(Resource.objects.prefetch_related("groups"), many=True).data,
        )


class RangeQuery(serializers.Serializer):
    start = DateTimeInput()
    end = DateTimeInput(help_text="After start, and at most 62 days after it.")

    def validate(self, attrs: dict[str, Any]) -> dict[str, Any]:
        if attrs["end"] <= attrs["start"]:
            raise serializers.ValidationError({"end": "Must be after start."})
        if attrs["end"] - attrs["start"] > MAX_RANGE:
            raise serializers.ValidationError({"end": "Ask for at most 62 days at a time."})
        return attrs


def _range_asked(request: Request) -> tuple[datetime, datetime]:
    """The range a calendar read asks for, read cheaply: it names what the answer is kept
    under. The query's whole check (``RangeQuery``, unknown parameters) runs when the answer
    is computed, so a kept answer's URL was valid; a range this read cannot take is checked
    here, and refused with the reasons."""
    start = rfc3339_instant(request.query_params.get("start"))
    end = rfc3339_instant(request.query_params.get("end"))
    if start is None or end is None or not timedelta(0) < end - start <= MAX_RANGE:
        query = valid_query(RangeQuery, request.query_params)
        return query["start"], query["end"]
    return start, end


class IntervalOutput(serializers.Serializer):
    start = serializers.DateTimeField()
    end = serializers.DateTimeField()


class AvailabilityOutput(serializers.Serializer):
    resource = serializers.CharField()
    start = serializers.DateTimeField()
    end = serializers.DateTimeField()
    free = IntervalOutput(many=True, help_text="The free intervals within [start, end).")


class AvailabilityApi(APIView):
    @extend_schema(parameters=[RangeQuery], responses=AvailabilityOutput)
    def get(self, request: Request, name: str) -> HttpResponse | Response:
        start_at, end_at = _range_asked(request)
        resource_id = CALENDAR_SETUP.answer(
            ("resource-id", name),
            lambda: Resource.objects.filter(name=name).values_list("pk", flat=True).first(),
        )
        if resource_id is None:
            raise Http404

        def available() -> dict[str, Any]:
            query = valid_query(RangeQuery, request.query_params)
            resource = Resource.objects.filter(pk=resource_id).first()
            if resource is None:
                raise Http404  # gone since: nothing kept
            free = resource_free_intervals(
                resource=resource, start_at=query["start"], end_at=query["end"]
            )
            return {
                "resource": resource.name,
                "start": query["start"],
                "end": query["end"],
                "free": [{"start": s, "end": e} for s, e in free],
            }

        generations = availability_generations(resource_id, start_at, end_at)
        return cached_json(request, generations, (), available)


class BusyOutput(serializers.Serializer):
    """What others see of someone else's reservation: only that the time is taken."""

    resources = serializers.ListField(child=serializers.CharField())
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()
    state = serializers.CharField()


class BusyApi(APIView):
    """Every active booking in a range, others' shown only as busy (calendar and scheduler)."""

    @extend_schema(parameters=[RangeQuery], responses=BusyOutput(many=True))
    def get(self, request: Request) -> HttpResponse | Response:
        def busy() -> Any:
            query = valid_query(RangeQuery, request.query_params)
            slots = busy_slots(start_at=query["start"], end_at=query["end"])
            return BusyOutput(slots, many=True).data

        return cached_json(request, busy_generations(*_range_asked(request)), (), busy)


class QuotaUseOutput(serializers.Serializer):
    """A quota policy that applies to the user, with the use of its current period."""

    policy = serializers.CharField()
    scope = serializers.CharField()
    period = serializers.ChoiceField(choices=QuotaPeriod.choices, allow_null=True)
    max_hours = serializers.FloatField(allow_null=True)
    max_count = serializers.IntegerField(allow_null=True)
    max_length_s = serializers.IntegerField(allow_null=True)
    min_notice_s = serializers.IntegerField(allow_null=True)
    max_advance_s = serializers.IntegerField(allow_null=True)
    max_future = serializers.IntegerField(allow_null=True)
    period_start = serializers.DateTimeField(required=False, help_text="Only with a period.")
    period_end = serializers.DateTimeField(required=False, help_text="Only with a period.")
    used_hours = serializers.FloatField(required=False)
    used_count = serializers.IntegerField(required=False)
    remaining_hours = serializers.FloatField(required=False, allow_null=True)
    remaining_count = serializers.IntegerField(required=False, allow_null=True)


class QuotaOutput(serializers.Serializer):
    policies = QuotaUseOutput(many=True)


class QuotaApi(APIView):
    @extend_schema(responses=QuotaOutput)
    def get(self, request: Request) -> HttpResponse | Response:
        user = request_user(request)
        now = timezone.now()
        # The use shown is of the current day, week and month: it is the same answer until
        # one of them ends or a reservation, policy or group membership changes.
        return cached_json(
            request,
            own_bookings_generations(user),
            (user.pk, *(period_bounds(period, now)[0] for period in QuotaPeriod.values)),
            lambda: {"policies": quota_summary(user=user, now=now)},
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
    start_at = DateTimeInput()
    end_at = DateTimeInput(help_text="After start_at.")
    reason = serializers.CharField(max_length=200)


class BlackoutFilter(serializers.Serializer):
    start = DateTimeInput(required=False, help_text="Only windows that end after this.")
    end = DateTimeInput(required=False, help_text="Only windows that begin before this.")


class BlackoutCreateOutput(serializers.Serializer):
    blackout = BlackoutOutput()
    conflicting_reservations = serializers.ListField(
        child=serializers.IntegerField(),
        help_text="Reservations in the window, for the admin to move or cancel.",
    )


class BlackoutListApi(APIView):
    pagination_class = Pagination

    @extend_schema(parameters=[BlackoutFilter], responses=BlackoutOutput(many=True))
    def get(self, request: Request) -> Response:
        query = valid_query(BlackoutFilter, request.query_params)
        qs = (
            Blackout.objects.overlapping(query.get("start"), query.get("end"))
            .prefetch_related("resources")
            .order_by("start_at", "pk")
        )
        return paginated_response(
            request=request, view=self, queryset=qs, serializer_class=BlackoutOutput
        )

    @extend_schema(request=BlackoutInput, responses={201: BlackoutCreateOutput})
    def post(self, request: Request) -> Response:
        data = valid_input(BlackoutInput, request.data)
        blackout, conflicts = services.blackout_create(
            by=request_user(request), ip=client_ip(request), **data
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
    max_hours = serializers.FloatField(required=False, allow_null=True, validators=[GreaterThan(0)])

    class Meta:
        model = QuotaPolicy
        fields = ["id", *services.QUOTA_FIELDS]


class QuotaPolicyListApi(APIView):
    permission_classes = [StaffVerified]
    pagination_class = Pagination

    @extend_schema(responses=QuotaPolicySerializer(many=True))
    def get(self, request: Request) -> Response:
        return paginated_response(
            request=request,
            view=self,
            queryset=QuotaPolicy.objects.order_by("name", "pk"),
            serializer_class=QuotaPolicySerializer,
        )

    @extend_schema(request=QuotaPolicySerializer, responses={201: QuotaPolicySerializer})
    def post(self, request: Request) -> Response:
        data = valid_input(QuotaPolicySerializer, request.data)
        policy = services.quota_policy_save(by=request_user(request), ip=client_ip(request), **data)
        return Response(QuotaPolicySerializer(policy).data, status=status.HTTP_201_CREATED)


class QuotaPolicyDetailApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(request=QuotaPolicySerializer, responses=QuotaPolicySerializer)
    def patch(self, request: Request, pk: int) -> Response:
        policy = get_object_or_404(QuotaPolicy, pk=pk)
        data = valid_input(QuotaPolicySerializer, request.data, instance=policy, partial=True)
        policy = services.quota_policy_save(
            by=request_user(request), policy=policy, ip=client_ip(request), **data
        )
        return Response(QuotaPolicySerializer(policy).data)


class ServiceInput(serializers.Serializer):
    enabled = serializers.BooleanField()
    reason = serializers.CharField(
        help_text="Why (audited).",
        error_messages={"required": "Say why.", "blank": "Say why."},
    )


class ResourceServiceApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(request=ServiceInput, responses=ResourceOutput)
    def post(self, request: Request, name: str) -> Response:
        data = valid_input(ServiceInput, request.data)
        resource = services.resource_set_service(
            resource=get_object_or_404(Resource, name=name),
            by=request_user(request),
            ip=client_ip(request),
            **data,
        )
        return Response(ResourceOutput(resource).data)
