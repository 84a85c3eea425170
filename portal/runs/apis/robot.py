"""The admins' robot console over the API: status, manual drive, e-stop, day log.

The answers carry the base station's own objects (``docs/agent-api.md``) under the keys named
here; their inner fields are the agent's and are described there.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from datetime import date

from django.core.exceptions import RequestDataTooBig
from django.shortcuts import get_object_or_404
from drf_spectacular.utils import OpenApiParameter, extend_schema
from rest_framework import serializers
from rest_framework.exceptions import ParseError, UnsupportedMediaType
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.throttling import BaseThrottle
from rest_framework.views import APIView

from basestation.contract import DIRECTIONS
from bookings.models import Resource
from core.accounts.permissions import StaffVerified
from core.api import GreaterThan, request_user, valid_input
from core.audit.services import client_ip
from core.openapi import errors
from portal.runs.services import robot

AGENT_OBJECT = "As the base station reports it (docs/agent-api.md)."
NOT_MOBILE = "The resource is not a mobile node (field `resource`), or the input is invalid."
NOT_MOBILE_RESOURCE = "The resource is not a mobile node (field `resource`)."


class RobotDriveInput(serializers.Serializer):
    velocity_mps = serializers.FloatField(
        min_value=0, help_text="At most the robot's max_velocity_mps."
    )
    direction = serializers.ChoiceField(choices=DIRECTIONS)
    ttl_s = serializers.FloatField(
        default=1.0,
        max_value=robot.MAX_MANUAL_TTL_S,
        validators=[GreaterThan(0)],
        help_text="How long the command holds; the robot stops after it (dead-man).",
    )
    force = serializers.BooleanField(default=False, help_text="Take over from a running run.")
    hold = serializers.BooleanField(
        default=False,
        help_text="One command of hold-to-drive, repeated while a button is held: the repeats "
        "of the same velocity and direction are audited once.",
    )
    reason = serializers.CharField(
        help_text="Why you drive by hand (audited).",
        error_messages={
            "required": "Say why you drive the robot by hand.",
            "blank": "Say why you drive the robot by hand.",
        },
    )


class StopInput(serializers.Serializer):
    """What the schema shows; a stop reads its body with :func:`stop_input` and is never
    refused for it."""

    reason = serializers.CharField(
        allow_blank=True,
        default="",
        help_text="Audited whole. Any text of any length, or none: a stop is refused only "
        "for who asks, never for its body (any other field, or a body that is not JSON, is "
        "accepted too). The base station keeps the first 200 characters.",
    )


def stop_input(request: Request) -> tuple[str, list[str]]:
    """The reason of a stop, and the fields it ignored, from whatever body came: the
    ``reason`` of a JSON (or form) object as text, else the body's own text. Never an error
    (DESIGN §8: a stop is refused only for authentication)."""
    try:
        raw = request.body
    except RequestDataTooBig:
        return "", ["body"]
    try:
        data = request.data
    except (ParseError, UnsupportedMediaType):
        data = None
    if isinstance(data, Mapping):
        value = data.get("reason", "")
        reason = value if isinstance(value, str) else json.dumps(value, ensure_ascii=False)
        return reason, sorted(str(name) for name in data if name != "reason")
    text = raw.decode("utf-8", "replace")
    return text, ["body"] if text.strip() else []


class ReleaseInput(serializers.Serializer):
    reason = serializers.CharField(
        help_text="Why it is safe to release the stop (audited).",
        error_messages={
            "required": "Say why it is safe to release the stop.",
            "blank": "Say why it is safe to release the stop.",
        },
    )
    reopen = serializers.BooleanField(
        default=False,
        help_text="Also put the robot back in service (bookings open), with the same reason: "
        "the stop's hold otherwise stays until an admin lifts it.",
    )


class RobotStatusOutput(serializers.Serializer):
    status = serializers.DictField(help_text=AGENT_OBJECT)
    battery = serializers.DictField(help_text=AGENT_OBJECT)


class RobotDriveOutput(serializers.Serializer):
    manual = serializers.DictField(allow_null=True, help_text=AGENT_OBJECT)
    aborted_run = serializers.CharField(allow_null=True)
    clock = serializers.FloatField(help_text="The base station's clock at the command (epoch s).")
    robot = serializers.DictField(
        help_text="Velocity, direction and position as the base station last read them "
        "(as in the status). " + AGENT_OBJECT
    )
    link = serializers.DictField(help_text="The radio link, as in the status. " + AGENT_OBJECT)


class RobotStopOutput(serializers.Serializer):
    estop = serializers.DictField(help_text=AGENT_OBJECT)
    aborted_run = serializers.CharField(allow_null=True)


class RobotReleaseOutput(serializers.Serializer):
    estop = serializers.DictField(help_text=AGENT_OBJECT)
    released = serializers.BooleanField()
    in_service = serializers.BooleanField(help_text="Whether the robot can be booked now.")
    hold_reason = serializers.CharField(help_text="Why it is held, if it is (empty if not).")


class RobotDayLogOutput(serializers.Serializer):
    date = serializers.DateField()
    timezone = serializers.CharField()
    entries = serializers.ListField(child=serializers.DictField(), help_text=AGENT_OBJECT)


def _mobile_named(name: str) -> Resource:
    return get_object_or_404(Resource, name=name)


class RobotStatusApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(responses={200: RobotStatusOutput, **errors(400, 503, e400=NOT_MOBILE)})
    def get(self, request: Request, name: str) -> Response:
        return Response(robot.robot_status(resource=_mobile_named(name)))


class RobotDriveApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(
        request=RobotDriveInput,
        responses={
            200: RobotDriveOutput,
            **errors(
                400,
                409,
                503,
                e400=NOT_MOBILE,
                e409="The base station refused: a run holds the robot, or the "
                "emergency stop is latched.",
            ),
        },
    )
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
    permission_classes = [StaffVerified]
    # Never throttled: a stop is refused only for who asks (the throttle counts calls
    # per user; a stop pressed again and again is a person in a hurry, not abuse).
    throttle_classes: list[type[BaseThrottle]] = []

    @extend_schema(
        request=StopInput,
        responses={200: RobotStopOutput, **errors(400, 503, e400=NOT_MOBILE_RESOURCE)},
    )
    def post(self, request: Request, name: str) -> Response:
        reason, ignored = stop_input(request)
        return Response(
            robot.robot_stop(
                resource=_mobile_named(name),
                by=request_user(request),
                ip=client_ip(request),
                reason=reason,
                ignored=ignored,
            )
        )


class RobotReleaseApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(
        request=ReleaseInput,
        responses={200: RobotReleaseOutput, **errors(400, 409, 503, e400=NOT_MOBILE)},
    )
    def post(self, request: Request, name: str) -> Response:
        data = valid_input(ReleaseInput, request.data)
        return Response(
            robot.robot_release(
                resource=_mobile_named(name),
                by=request_user(request),
                ip=client_ip(request),
                **data,
            )
        )


class RobotLogApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(
        parameters=[OpenApiParameter("day", date, OpenApiParameter.PATH, description="UTC day.")],
        responses={200: RobotDayLogOutput, **errors(400, 503, e400=NOT_MOBILE)},
    )
    def get(self, request: Request, name: str, day: str) -> Response:
        try:
            if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", day):
                raise ValueError(day)
            parsed = date.fromisoformat(day)
        except ValueError as exc:
            raise serializers.ValidationError({"day": ["The day is YYYY-MM-DD."]}) from exc
        return Response(
            robot.robot_day_log(resource=_mobile_named(name), by=request_user(request), day=parsed)
        )
