"""A robot's self-checks over the API (admins): its checks and baseline, book one, choose the
baseline. The same services as the console's buttons (``portal.runs.services.self_check``)."""

from __future__ import annotations

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.models import Resource
from core.accounts.permissions import StaffVerified
from core.api import request_user, valid_input
from core.audit.services import client_ip
from core.openapi import ClosedSerializer, errors
from portal.runs.apis.reservations import request_door
from portal.runs.models import SelfCheck
from portal.runs.selectors import (
    self_check_baseline_of,
    self_check_schedule_of,
    self_checks_of,
)
from portal.runs.self_check import RULES
from portal.runs.services.self_check import (
    self_check_baseline_set,
    self_check_book,
    self_check_schedule_set,
)

FIGURES = (
    "The figures by name (null: not measured): "
    + "; ".join(
        f"`{name}` {rule.label}{f' ({rule.unit})' if rule.unit else ''}"
        for name, rule in RULES.items()
    )
    + "."
)


class SelfCheckOutput(serializers.ModelSerializer):
    run = serializers.IntegerField(source="run_id")
    resource = serializers.CharField(source="resource.name")
    start_at = serializers.DateTimeField(source="run.start_at")
    figures = serializers.DictField(
        child=serializers.FloatField(allow_null=True), help_text=FIGURES
    )
    problems = serializers.ListField(
        child=serializers.CharField(), help_text="Each figure out of tolerance, in words."
    )
    baseline = serializers.DictField(
        child=serializers.FloatField(allow_null=True),
        allow_null=True,
        help_text="The figures it was judged against (null: the limits alone).",
    )

    class Meta:
        model = SelfCheck
        fields = [
            "id", "run", "resource", "start_at", "state", "check_velocity_mps", "accel_mps2",
            "lap_m", "figures", "problems", "baseline", "reason", "evaluated_at", "created_at",
        ]  # fmt: skip


class SelfCheckScheduleOutput(serializers.Serializer):
    at = serializers.TimeField(
        format="%H:%M", help_text="Every day at this time (the testbed's wall clock)."
    )
    set_by = serializers.CharField(
        source="set_by.username", help_text="The admin the daily booking is made for."
    )


class SelfCheckListOutput(serializers.Serializer):
    checks = SelfCheckOutput(many=True, help_text="Newest first, at most 100.")
    baseline = serializers.DictField(
        child=serializers.FloatField(allow_null=True),
        allow_null=True,
        help_text="What the next check is judged against (null: none yet).",
    )
    baseline_check = serializers.IntegerField(
        allow_null=True, help_text="The check the baseline came from."
    )
    schedule = SelfCheckScheduleOutput(allow_null=True, help_text="Null: booked by hand only.")


class SelfCheckScheduleInput(ClosedSerializer):
    at = serializers.TimeField(
        allow_null=True,
        help_text="Book the robot's self-check every day at this time (HH:MM, the testbed's "
        "wall clock) or in the first free slot after it; null stops.",
    )


class SelfCheckBookInput(ClosedSerializer):
    start_at = serializers.DateTimeField(
        required=False, help_text="When it starts; omitted: the robot's first free slot."
    )


def _robot(name: str) -> Resource:
    return get_object_or_404(Resource, name=name)


class SelfCheckListApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(responses={200: SelfCheckListOutput, **errors(404)})
    def get(self, request: Request, name: str) -> Response:
        robot = _robot(name)
        baseline = self_check_baseline_of(robot)
        return Response(
            {
                "checks": SelfCheckOutput(self_checks_of(robot), many=True).data,
                "baseline": baseline.figures if baseline is not None else None,
                "baseline_check": baseline.source_id if baseline is not None else None,
                "schedule": _schedule(robot),
            }
        )

    @extend_schema(
        request=SelfCheckBookInput,
        responses={
            201: SelfCheckOutput,
            **errors(400, 404, 409, e409="No free slot, or the booking was refused."),
        },
    )
    def post(self, request: Request, name: str) -> Response:
        data = valid_input(SelfCheckBookInput, request.data)
        check = self_check_book(
            resource=_robot(name),
            by=request_user(request),
            start_at=data.get("start_at"),
            via=request_door(request),
            ip=client_ip(request),
        )
        return Response(SelfCheckOutput(check).data, status=status.HTTP_201_CREATED)


def _schedule(robot: Resource) -> dict[str, str] | None:
    schedule = self_check_schedule_of(robot)
    return SelfCheckScheduleOutput(schedule).data if schedule is not None else None


class SelfCheckScheduleApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(
        request=SelfCheckScheduleInput,
        responses={200: SelfCheckScheduleOutput, 204: None, **errors(400, 404)},
    )
    def put(self, request: Request, name: str) -> Response:
        data = valid_input(SelfCheckScheduleInput, request.data)
        schedule = self_check_schedule_set(
            resource=_robot(name), by=request_user(request), at=data["at"], ip=client_ip(request)
        )
        if schedule is None:
            return Response(status=status.HTTP_204_NO_CONTENT)
        return Response(SelfCheckScheduleOutput(schedule).data)


class SelfCheckBaselineApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(request=None, responses={200: SelfCheckOutput, **errors(400, 404)})
    def post(self, request: Request, pk: int) -> Response:
        check = get_object_or_404(SelfCheck.objects.select_related("resource", "run"), pk=pk)
        self_check_baseline_set(check=check, by=request_user(request), ip=client_ip(request))
        return Response(SelfCheckOutput(check).data)
