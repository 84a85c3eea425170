"""The queue through the API: ask for a run as soon as possible, see where it stands, withdraw
it; admins pause, resume and reorder."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from django.http import StreamingHttpResponse
from django.shortcuts import get_object_or_404
from django.utils import timezone
from drf_spectacular.utils import OpenApiResponse, extend_schema, extend_schema_field
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.selectors import resources_bookable
from core.accounts.permissions import StaffVerified
from core.api import DateTimeInput, Pagination, paginated_data, request_user, valid_input
from core.audit.idempotency import idempotent
from core.audit.services import client_ip
from core.openapi import ClosedSerializer, errors
from portal.experiments.selectors import experiments_visible
from portal.queue.campaigns import (
    campaign_cancel,
    campaign_create,
    campaign_pause,
    campaign_progress,
    campaign_requests,
    campaign_resume,
)
from portal.queue.models import Campaign, QueueControl, QueueRequest, RequestState
from portal.queue.package import campaign_package_response
from portal.queue.results import (
    METRICS,
    campaign_results,
    campaign_results_json,
    campaign_runs_completed,
)
from portal.queue.selectors import (
    Place,
    campaigns_visible,
    queue_control,
    queue_places,
    queue_requests_visible,
)
from portal.queue.services import (
    queue_pause,
    queue_request_cancel,
    queue_request_reorder,
    queue_request_submit,
    queue_resume,
)
from portal.queue.sweep import ORDERS
from portal.runs.apis.runs import DownloadApi, ZipRenderer


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


# Pausing and resuming the queue: one staff action each, the same shape. (A comment, not a
# docstring: the OpenAPI description would take it for the operations' own.)
class _QueueSwitchApi(APIView):
    permission_classes = [StaffVerified]
    switch: Callable[..., QueueControl]

    @extend_schema(request=ReasonInput, responses=QueueStateOutput)
    def post(self, request: Request) -> Response:
        data = valid_input(ReasonInput, request.data)
        control = type(self).switch(
            by=request_user(request), reason=data.get("reason", ""), ip=client_ip(request)
        )
        return Response(QueueStateOutput(control).data)


class QueuePauseApi(_QueueSwitchApi):
    switch = staticmethod(queue_pause)


class QueueResumeApi(_QueueSwitchApi):
    switch = staticmethod(queue_resume)


class CampaignParametersInput(serializers.Serializer):
    velocity_mps = serializers.JSONField(
        help_text="m/s: a value, a list, or a range {from, to, step} (both ends included)."
    )
    direction = serializers.JSONField(help_text="cw, ccw, or a list of both.")
    duration_s = serializers.JSONField(help_text="Seconds: a value, a list or a range.")


class CampaignInput(ClosedSerializer):
    """A campaign file (YAML or JSON for ``amazing campaign create``): a one-segment program
    swept over its parameters' values, every combination ``repeats`` times."""

    title = serializers.CharField(max_length=150)
    robot = serializers.CharField()
    nodes = serializers.ListField(child=serializers.CharField(), required=False)
    parameters = CampaignParametersInput()
    repeats = serializers.IntegerField(required=False, min_value=1, max_value=100)
    order = serializers.ChoiceField(choices=ORDERS, required=False)
    seed = serializers.IntegerField(required=False, allow_null=True)
    earliest_at = DateTimeInput(required=False)
    latest_end_at = DateTimeInput()
    hours = serializers.ListField(
        child=serializers.IntegerField(min_value=0, max_value=24),
        min_length=2,
        max_length=2,
        required=False,
        help_text="Allowed hours of the testbed's day [from, to]; [22, 6] is nights only.",
    )


class CampaignRunOutput(serializers.Serializer):
    request = serializers.IntegerField(source="pk")
    parameters = serializers.JSONField()
    state = serializers.CharField(help_text="The queued request's: waiting, booked, expired…")
    reason = serializers.CharField()
    reservation = serializers.IntegerField(source="reservation_id", allow_null=True)
    run = serializers.SerializerMethodField()

    @extend_schema_field(serializers.DictField(allow_null=True))
    def get_run(self, request: QueueRequest) -> dict[str, Any] | None:
        run = getattr(request.reservation, "run", None) if request.reservation else None
        return {"id": run.pk, "state": run.state} if run is not None else None


class CampaignOutput(serializers.ModelSerializer):
    owner = serializers.CharField(source="owner.username")
    robot = serializers.CharField(source="robot.name")
    progress = serializers.SerializerMethodField()
    runs = serializers.SerializerMethodField()

    class Meta:
        model = Campaign
        fields = ["id", "title", "owner", "robot", "state", "progress", "runs", "created_at"]

    @extend_schema_field(serializers.DictField())
    def get_progress(self, campaign: Campaign) -> dict[str, Any]:
        return campaign_progress(campaign)

    @extend_schema_field(CampaignRunOutput(many=True))
    def get_runs(self, campaign: Campaign) -> Any:
        return CampaignRunOutput(campaign_requests(campaign), many=True).data


class CampaignCancelInput(serializers.Serializer):
    cancel_booked = serializers.BooleanField(
        default=False, help_text="Also cancel the runs already booked (not those ended)."
    )
    reason = serializers.CharField(required=False, allow_blank=True, max_length=1000)


def _campaign(request: Request, pk: int) -> Campaign:
    return get_object_or_404(campaigns_visible(user=request_user(request)), pk=pk)


class CampaignListApi(APIView):
    pagination_class = Pagination

    @extend_schema(responses=CampaignOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = campaigns_visible(user=request_user(request)).order_by("-created_at", "-pk")

        def represent(page: list[Any]) -> list[dict[str, Any]]:
            return list(CampaignOutput(page, many=True).data)

        return Response(paginated_data(request=request, queryset=qs, represent=represent))

    @extend_schema(request=CampaignInput, responses={201: CampaignOutput})
    @idempotent
    def post(self, request: Request) -> Response:
        valid_input(CampaignInput, request.data)  # the shape; the service reads the file
        campaign = campaign_create(
            owner=request_user(request), spec=dict(request.data), ip=client_ip(request)
        )
        return Response(CampaignOutput(campaign).data, status=status.HTTP_201_CREATED)


class CampaignDetailApi(APIView):
    @extend_schema(responses=CampaignOutput)
    def get(self, request: Request, pk: int) -> Response:
        return Response(CampaignOutput(_campaign(request, pk)).data)


class CampaignPauseApi(APIView):
    @extend_schema(request=None, responses={200: CampaignOutput, **errors(409)})
    def post(self, request: Request, pk: int) -> Response:
        paused = campaign_pause(
            campaign=_campaign(request, pk), by=request_user(request), ip=client_ip(request)
        )
        return Response(CampaignOutput(paused).data)


class CampaignResumeApi(APIView):
    @extend_schema(request=None, responses={200: CampaignOutput, **errors(409)})
    def post(self, request: Request, pk: int) -> Response:
        resumed = campaign_resume(
            campaign=_campaign(request, pk), by=request_user(request), ip=client_ip(request)
        )
        return Response(CampaignOutput(resumed).data)


class CampaignCancelApi(APIView):
    @extend_schema(request=CampaignCancelInput, responses=CampaignOutput)
    def post(self, request: Request, pk: int) -> Response:
        data = valid_input(CampaignCancelInput, request.data)
        cancelled = campaign_cancel(
            campaign=_campaign(request, pk),
            by=request_user(request),
            cancel_booked=data["cancel_booked"],
            reason=data.get("reason", ""),
            ip=client_ip(request),
        )
        return Response(CampaignOutput(cancelled).data)


class SpreadOutput(serializers.Serializer):
    mean = serializers.FloatField()
    sd = serializers.FloatField(allow_null=True, help_text="Sample sd over the repeats.")
    n = serializers.IntegerField(help_text="Repeats with samples in the segment.")


class ResultGroupOutput(serializers.Serializer):
    velocity_mps = serializers.FloatField()
    direction = serializers.CharField()
    duration_s = serializers.FloatField()
    runs = serializers.ListField(child=serializers.IntegerField())
    metrics = serializers.DictField(
        child=SpreadOutput(), help_text="Per statistic (see `metrics`): mean and spread."
    )


class CampaignResultsOutput(serializers.Serializer):
    campaign = serializers.IntegerField()
    completed = serializers.IntegerField(help_text="Completed runs the results come from.")
    metrics = serializers.DictField(
        child=serializers.CharField(), help_text="Each statistic's name and what it is."
    )
    groups = ResultGroupOutput(many=True)


class CampaignResultsApi(APIView):
    """Per combination of the campaign's values: its completed runs' segment statistics,
    the mean over the repeats and their sample sd."""

    @extend_schema(responses=CampaignResultsOutput)
    def get(self, request: Request, pk: int) -> Response:
        campaign = _campaign(request, pk)
        completed = campaign_runs_completed(campaign)
        groups = campaign_results(completed)
        return Response(
            {
                "campaign": campaign.pk,
                "completed": len(completed),
                "metrics": dict(METRICS),
                "groups": campaign_results_json(groups),
            }
        )


class CampaignPackageApi(DownloadApi):
    """Every completed run's package in a folder of its own, `manifest.json`, and
    `campaign.json`: a Frictionless Data Package of every run's parameters and the results
    (docs/run-package.md)."""

    renderer_classes = [*APIView.renderer_classes, ZipRenderer]

    @extend_schema(
        responses={
            (200, "application/zip"): OpenApiResponse(
                bytes, description="run-<id>/ folders, manifest.json, then campaign.json."
            )
        }
    )
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        return campaign_package_response(request, _campaign(request, pk))
