"""The admins' robot console over the API: status, manual drive, e-stop, day log."""

from __future__ import annotations

from datetime import date

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers
from rest_framework.permissions import IsAdminUser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from basestation.contract import DIRECTIONS
from bookings.models import Resource
from portal.api import request_user, valid_input
from portal.audit.services import client_ip
from portal.runs.services import robot


class RobotDriveInput(serializers.Serializer):
    velocity_mps = serializers.FloatField()
    direction = serializers.ChoiceField(choices=DIRECTIONS)
    ttl_s = serializers.FloatField(default=1.0)
    force = serializers.BooleanField(default=False)
    reason = serializers.CharField(allow_blank=True, default="")


class ReasonInput(serializers.Serializer):
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
        data = valid_input(RobotDriveInput, request.data)
        return Response(
            robot.robot_drive(
                resource=_mobile_named(name),
                by=request_user(request),
                ip=client_ip(request),
                **data,
            )
        )


class RobotStopApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=ReasonInput, responses={200: dict})
    def post(self, request: Request, name: str) -> Response:
        data = valid_input(ReasonInput, request.data or {})
        return Response(
            robot.robot_stop(
                resource=_mobile_named(name),
                by=request_user(request),
                ip=client_ip(request),
                **data,
            )
        )


class RobotReleaseApi(APIView):
    permission_classes = [IsAdminUser]

    @extend_schema(request=ReasonInput, responses={200: dict})
    def post(self, request: Request, name: str) -> Response:
        data = valid_input(ReasonInput, request.data or {})
        return Response(
            robot.robot_release(
                resource=_mobile_named(name),
                by=request_user(request),
                ip=client_ip(request),
                **data,
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
            robot.robot_day_log(resource=_mobile_named(name), by=request_user(request), day=parsed)
        )
