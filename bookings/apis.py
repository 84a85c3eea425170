from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

from django.shortcuts import get_object_or_404
from django.utils import timezone
from drf_spectacular.utils import OpenApiParameter, extend_schema
from rest_framework import serializers, status
from rest_framework.permissions import IsAdminUser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings import services
from bookings.choices import QuotaPeriod
from bookings.models import Blackout, QuotaPolicy, Resource, ResourceGroup
from bookings.quotas import quota_summary
from bookings.selectors import items_overlapping, resource_free_intervals
from portal.accounts.models import User
from portal.api import request_user, valid_input
from portal.audit.services import client_ip

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
        query = valid_input(RangeQuery, request.query_params)
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


class BusyOutput(serializers.Serializer):
    """What others see of someone else's reservation: only that the time is taken."""

    resources = serializers.ListField(child=serializers.CharField())
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()
    state = serializers.CharField()


class BusyApi(APIView):
    """Every active booking in a range, others' shown only as busy (calendar and scheduler)."""

    @extend_schema(parameters=[RangeQuery], responses=BusyOutput(many=True))
    def get(self, request: Request) -> Response:
        query = valid_input(RangeQuery, request.query_params)
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
        return Response({"policies": quota_summary(user=request_user(request), now=timezone.now())})


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
            query = valid_input(RangeQuery, request.query_params)
            qs = qs.filter(start_at__lt=query["end"], end_at__gt=query["start"])
        return Response(BlackoutOutput(qs[:500], many=True).data)

    @extend_schema(request=BlackoutInput, responses={201: dict})
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
        data = valid_input(QuotaPolicySerializer, request.data)
        policy = services.quota_policy_save(by=request_user(request), ip=client_ip(request), **data)
        return Response(QuotaPolicySerializer(policy).data, status=status.HTTP_201_CREATED)


class QuotaPolicyDetailApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=QuotaPolicySerializer, responses=QuotaPolicySerializer)
    def patch(self, request: Request, pk: int) -> Response:
        policy = get_object_or_404(QuotaPolicy, pk=pk)
        serializer = QuotaPolicySerializer(policy, data=request.data, partial=True)
        serializer.is_valid(raise_exception=True)
        policy = services.quota_policy_save(
            by=request_user(request),
            policy=policy,
            ip=client_ip(request),
            **serializer.validated_data,
        )
        return Response(QuotaPolicySerializer(policy).data)


class ServiceInput(serializers.Serializer):
    enabled = serializers.BooleanField()
    reason = serializers.CharField(allow_blank=True, default="")


class ResourceServiceApi(APIView):
    permission_classes = [IsAdminUser]

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
