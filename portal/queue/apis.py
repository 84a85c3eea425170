"""The queue through the API: ask for a run as soon as possible, see where it stands, withdraw
it; admins pause, resume and reorder."""

from __future__ import annotations

from typing import Any

from django.shortcuts import get_object_or_404
from django.utils import timezone
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.selectors import resources_bookable
from core.accounts.permissions import StaffVerified
from core.api import DateTimeInput, Pagination, paginated_data, request_user, valid_input
from core.audit.idempotency import idempotent
from core.audit.services import client_ip
from core.openapi import errors
from portal.experiments.selectors import experiments_visible
from portal.queue.models import QueueControl, QueueRequest, RequestState
from portal.queue.selectors import Place, queue_control, queue_places, queue_requests_visible
from portal.queue.services import (
    queue_pause,
    queue_request_cancel,
    queue_request_reorder,
    queue_request_submit,
    queue_resume,
)


class QueueRequestOutput(serializers.ModelSerializer):
    owner = serializers.CharField(source="owner.username")
    robot = serializers.CharField(source="robot.name")
    nodes = serializers.SerializerMethodField()
    position = serializers.SerializerMethodField(
        help_text="Its place among the waiting requests (1 is next); null unless waiting."
    )
    estimated_start_at = serializers.SerializerMethodField(
        help_text="Where it would start if the calendar did not change (the requests before "
        "it taking their slots first); null if not waiting or no slot fits before its latest "
        "end. For a booked request, its reservation's start."
    )

    class Meta:
        model = QueueRequest
        fields = [
            "id",
            "owner",
            "title",
            "experiment",
            "robot",
            "nodes",
            "duration_s",
            "earliest_at",
            "latest_end_at",
            "hours_from",
            "hours_to",
            "state",
            "reason",
            "priority",
            "position",
            "estimated_start_at",
            "reservation",
            "submitted_at",
        ]

    def _place(self, request: QueueRequest) -> Place | None:
        places: dict[int, Place] = self.context.get("places", {})
        return places.get(request.pk)

    def get_nodes(self, request: QueueRequest) -> list[str]:
        return sorted(node.name for node in request.nodes.all())

    def get_position(self, request: QueueRequest) -> int | None:
        place = self._place(request)
        return place.position if place is not None else None

    def get_estimated_start_at(self, request: QueueRequest) -> str | None:
        if request.state == RequestState.BOOKED and request.reservation is not None:
            return serializers.DateTimeField().to_representation(request.reservation.start_at)
        place = self._place(request)
        if place is None or place.estimated_start_at is None:
            return None
        return serializers.DateTimeField().to_representation(place.estimated_start_at)


def _places() -> dict[int, Place]:
    return queue_places(now=timezone.now())


class QueueRequestInput(serializers.Serializer):
    experiment = serializers.IntegerField(help_text="The experiment to run (yours).")
    robot = serializers.SlugRelatedField(slug_field="name", queryset=resources_bookable())
    nodes = serializers.SlugRelatedField(
        slug_field="name",
        queryset=resources_bookable(),
        many=True,
        required=False,
        help_text="Fixed nodes held with the robot.",
    )
    duration_s = serializers.IntegerField(
        required=False,
        min_value=1,
        help_text="How long to book; the program's length rounded up to a minute if not given.",
    )
    earliest_at = DateTimeInput(required=False, help_text="No sooner than this; now if absent.")
    latest_end_at = DateTimeInput(help_text="Expires if it cannot end by then.")
    hours_from = serializers.IntegerField(
        required=False, allow_null=True, min_value=0, max_value=23
    )
    hours_to = serializers.IntegerField(
        required=False,
        allow_null=True,
        min_value=1,
        max_value=24,
        help_text="Allowed hours of the testbed's day, from hours_from to hours_to (22 to 6: "
        "nights only).",
    )
    title = serializers.CharField(max_length=200, required=False, allow_blank=True)


class ReasonInput(serializers.Serializer):
    reason = serializers.CharField(required=False, allow_blank=True, max_length=1000)


class ReorderInput(serializers.Serializer):
    priority = serializers.IntegerField(
        min_value=-1000,
        max_value=1000,
        help_text="Higher goes first, before the fair-share order; 0 is the usual.",
    )
    reason = serializers.CharField(max_length=1000)


class QueueStateOutput(serializers.ModelSerializer):
    changed_by = serializers.CharField(source="changed_by.username", allow_null=True)

    class Meta:
        model = QueueControl
        fields = ["paused", "reason", "changed_by", "changed_at"]


class QueueListApi(APIView):
    pagination_class = Pagination

    @extend_schema(responses=QueueRequestOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = queue_requests_visible(user=request_user(request)).order_by("-submitted_at", "-pk")
        places = _places()

        def represent(page: list[Any]) -> list[dict[str, Any]]:
            serializer = QueueRequestOutput(page, many=True, context={"places": places})
            return list(serializer.data)

        return Response(paginated_data(request=request, queryset=qs, represent=represent))

    @extend_schema(
        request=QueueRequestInput,
        responses={201: QueueRequestOutput, **errors(404, e404="The experiment is not found.")},
    )
    @idempotent
    def post(self, request: Request) -> Response:
        user = request_user(request)
        data = valid_input(QueueRequestInput, request.data)
        experiment = get_object_or_404(experiments_visible(user=user), pk=data.pop("experiment"))
        queued = queue_request_submit(
            owner=user, experiment=experiment, ip=client_ip(request), **data
        )
        return Response(
            QueueRequestOutput(queued, context={"places": _places()}).data,
            status=status.HTTP_201_CREATED,
        )


class QueueDetailApi(APIView):
    def _get(self, request: Request, pk: int) -> QueueRequest:
        return get_object_or_404(queue_requests_visible(user=request_user(request)), pk=pk)

    @extend_schema(responses=QueueRequestOutput)
    def get(self, request: Request, pk: int) -> Response:
        queued = self._get(request, pk)
        return Response(QueueRequestOutput(queued, context={"places": _places()}).data)

    @extend_schema(
        request=ReasonInput,
        responses={200: QueueRequestOutput, **errors(409, e409="The request is not waiting.")},
    )
    def delete(self, request: Request, pk: int) -> Response:
        data = valid_input(ReasonInput, request.data)
        cancelled = queue_request_cancel(
            request=self._get(request, pk),
            by=request_user(request),
            reason=data.get("reason", ""),
            ip=client_ip(request),
        )
        return Response(QueueRequestOutput(cancelled).data)


class QueueReorderApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(
        request=ReorderInput,
        responses={200: QueueRequestOutput, **errors(409, e409="The request is not waiting.")},
    )
    def post(self, request: Request, pk: int) -> Response:
        data = valid_input(ReorderInput, request.data)
        reordered = queue_request_reorder(
            request=get_object_or_404(QueueRequest, pk=pk),
            by=request_user(request),
            ip=client_ip(request),
            **data,
        )
        return Response(QueueRequestOutput(reordered, context={"places": _places()}).data)


class QueueStateApi(APIView):
    @extend_schema(responses=QueueStateOutput)
    def get(self, request: Request) -> Response:
        return Response(QueueStateOutput(queue_control()).data)


class QueuePauseApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(request=ReasonInput, responses=QueueStateOutput)
    def post(self, request: Request) -> Response:
        data = valid_input(ReasonInput, request.data)
        control = queue_pause(
            by=request_user(request), reason=data.get("reason", ""), ip=client_ip(request)
        )
        return Response(QueueStateOutput(control).data)


class QueueResumeApi(APIView):
    permission_classes = [StaffVerified]

    @extend_schema(request=ReasonInput, responses=QueueStateOutput)
    def post(self, request: Request) -> Response:
        data = valid_input(ReasonInput, request.data)
        control = queue_resume(
            by=request_user(request), reason=data.get("reason", ""), ip=client_ip(request)
        )
        return Response(QueueStateOutput(control).data)
