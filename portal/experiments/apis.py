from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from typing import Any

from asgiref.sync import sync_to_async
from django.core.handlers.asgi import ASGIRequest
from django.http import StreamingHttpResponse
from django.shortcuts import get_object_or_404
from drf_spectacular.utils import OpenApiParameter, extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from portal.experiments.models import Experiment, Run
from portal.experiments.selectors import (
    experiments_visible,
    run_report,
    run_report_json,
    run_samples,
    run_samples_csv,
    run_samples_json,
    runs_visible,
)
from portal.experiments.services import experiment_create, experiment_update


class SegmentSerializer(serializers.Serializer):
    velocity_mps = serializers.FloatField(min_value=0)
    direction = serializers.ChoiceField(choices=["cw", "ccw"])
    duration_s = serializers.FloatField(min_value=0.001)


class ExperimentOutput(serializers.ModelSerializer):
    segments = SegmentSerializer(many=True)
    duration_s = serializers.FloatField(read_only=True)
    owner = serializers.CharField(source="owner.username")

    class Meta:
        model = Experiment
        fields = ["id", "title", "segments", "duration_s", "owner", "created_at", "updated_at"]


class ExperimentInput(serializers.Serializer):
    title = serializers.CharField(max_length=200)
    # Checked by the service, which knows the robots' limits and names the segment at fault.
    segments = serializers.JSONField()


class ExperimentListApi(APIView):
    @extend_schema(responses=ExperimentOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = experiments_visible(user=request.user)  # type: ignore[arg-type]
        return Response(ExperimentOutput(qs, many=True).data)

    @extend_schema(request=ExperimentInput, responses={201: ExperimentOutput})
    def post(self, request: Request) -> Response:
        data = _valid(ExperimentInput, request.data)
        experiment = experiment_create(owner=request.user, **data)  # type: ignore[arg-type]
        return Response(ExperimentOutput(experiment).data, status=status.HTTP_201_CREATED)


class ExperimentDetailApi(APIView):
    def _get(self, request: Request, pk: int) -> Experiment:
        return get_object_or_404(experiments_visible(user=request.user), pk=pk)  # type: ignore[arg-type]

    @extend_schema(responses=ExperimentOutput)
    def get(self, request: Request, pk: int) -> Response:
        return Response(ExperimentOutput(self._get(request, pk)).data)

    @extend_schema(request=ExperimentInput, responses=ExperimentOutput)
    def put(self, request: Request, pk: int) -> Response:
        experiment = self._get(request, pk)
        data = _valid(ExperimentInput, request.data)
        return Response(ExperimentOutput(experiment_update(experiment=experiment, **data)).data)


def _valid(serializer_class: type[serializers.Serializer], data: Any) -> dict[str, Any]:
    serializer = serializer_class(data=data)
    serializer.is_valid(raise_exception=True)
    return dict(serializer.validated_data)


class RunEventOutput(serializers.Serializer):
    from_state = serializers.CharField()
    to_state = serializers.CharField()
    at = serializers.DateTimeField()
    reason = serializers.CharField()


class RunOutput(serializers.ModelSerializer):
    reservation = serializers.IntegerField(source="reservation_id")
    resource = serializers.CharField(source="resource.name")
    owner = serializers.CharField(source="reservation.owner.username")
    segments = SegmentSerializer(many=True)
    sample_count = serializers.SerializerMethodField()
    events = RunEventOutput(many=True)

    class Meta:
        model = Run
        fields = [
            "id",
            "title",
            "reservation",
            "resource",
            "owner",
            "experiment",
            "segments",
            "start_at",
            "end_at",
            "state",
            "reason",
            "last_seq",
            "sample_count",
            "agent_sample_count",
            "rail_length_m",
            "events",
        ]

    def get_sample_count(self, run: Run) -> int:
        return run.samples.count()


class RunListApi(APIView):
    @extend_schema(responses=RunOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = runs_visible(user=request.user).prefetch_related("events")  # type: ignore[arg-type]
        state = request.query_params.get("state")
        if state:
            qs = qs.filter(state=state)
        return Response(RunOutput(qs[:200], many=True).data)


class RunDetailApi(APIView):
    @extend_schema(responses=RunOutput)
    def get(self, request: Request, pk: int) -> Response:
        run = get_object_or_404(runs_visible(user=request.user), pk=pk)  # type: ignore[arg-type]
        return Response(RunOutput(run).data)


class SampleOutput(serializers.Serializer):
    seq = serializers.IntegerField()
    t = serializers.DateTimeField()
    segment = serializers.IntegerField(allow_null=True)
    commanded_velocity_mps = serializers.FloatField()
    velocity_mps = serializers.FloatField()
    direction = serializers.CharField()
    battery_v = serializers.FloatField()
    track_m = serializers.FloatField()
    fix_quality = serializers.IntegerField(allow_null=True)
    lat_deg = serializers.FloatField(allow_null=True)
    lon_deg = serializers.FloatField(allow_null=True)
    grid_id = serializers.CharField(allow_null=True)
    lap = serializers.IntegerField(allow_null=True)


class SamplesQuery(serializers.Serializer):
    after = serializers.IntegerField(min_value=0, default=0)
    limit = serializers.IntegerField(min_value=1, max_value=10000, default=1000)


class RunSamplesApi(APIView):
    @extend_schema(
        parameters=[
            OpenApiParameter(
                "after", int, description="Return samples with seq greater than this."
            ),
            OpenApiParameter("limit", int, description="At most this many (≤ 10 000)."),
        ],
        responses=SampleOutput(many=True),
    )
    def get(self, request: Request, pk: int) -> Response:
        run = get_object_or_404(runs_visible(user=request.user), pk=pk)  # type: ignore[arg-type]
        query = _valid(SamplesQuery, request.query_params)
        rows = list(run_samples(run=run, after_seq=query["after"], limit=query["limit"]))
        return Response(
            {
                "run": run.pk,
                "state": run.state,
                "samples": SampleOutput(rows, many=True).data,
                "last_seq": rows[-1].seq if rows else query["after"],
            }
        )


def samples_csv_response(run: Run, *, asynchronous: bool = False) -> StreamingHttpResponse:
    """All samples of a run as CSV, streamed (never built in memory)."""
    return _download(run_samples_csv(run=run), run, "csv", "text/csv", asynchronous)


def samples_json_response(run: Run, *, asynchronous: bool = False) -> StreamingHttpResponse:
    """All samples of a run as one JSON document, streamed."""
    return _download(run_samples_json(run=run), run, "json", "application/json", asynchronous)


def _download(
    chunks: Iterator[str], run: Run, extension: str, media_type: str, asynchronous: bool
) -> StreamingHttpResponse:
    """Under ASGI the chunks come through an async iterator that reads the database in the
    request's sync thread, so the server is never blocked and Django does not buffer it."""
    content: Iterator[str] | AsyncIterator[str] = _async_chunks(chunks) if asynchronous else chunks
    response = StreamingHttpResponse(content, content_type=f"{media_type}; charset=utf-8")
    response["Content-Disposition"] = f'attachment; filename="amazing-run-{run.pk}.{extension}"'
    return response


def _next_or_none(chunks: Iterator[str]) -> str | None:
    return next(chunks, None)


async def _async_chunks(chunks: Iterator[str]) -> AsyncIterator[str]:
    next_chunk = sync_to_async(_next_or_none, thread_sensitive=True)
    while True:
        chunk = await next_chunk(chunks)
        if chunk is None:
            return
        yield chunk


def is_asgi(request: Any) -> bool:
    return isinstance(getattr(request, "_request", request), ASGIRequest)


class RunSamplesCsvApi(APIView):
    @extend_schema(responses={(200, "text/csv"): str})
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        run = get_object_or_404(runs_visible(user=request.user), pk=pk)  # type: ignore[arg-type]
        return samples_csv_response(run, asynchronous=is_asgi(request))


class RunSamplesJsonApi(APIView):
    @extend_schema(responses={(200, "application/json"): dict})
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        run = get_object_or_404(runs_visible(user=request.user), pk=pk)  # type: ignore[arg-type]
        return samples_json_response(run, asynchronous=is_asgi(request))


class AnalysisQuery(serializers.Serializer):
    pass_at_m = serializers.FloatField(
        required=False, help_text="Where along the rail (m from its origin) to list passes."
    )


class RunAnalysisApi(APIView):
    """Per-segment statistics, laps, passes at a position and missing samples of a run."""

    @extend_schema(parameters=[AnalysisQuery], responses={200: dict})
    def get(self, request: Request, pk: int) -> Response:
        run = get_object_or_404(runs_visible(user=request.user), pk=pk)  # type: ignore[arg-type]
        query = _valid(AnalysisQuery, request.query_params)
        try:
            report = run_report(run=run, pass_at_m=query.get("pass_at_m"))
        except ValueError as exc:
            raise serializers.ValidationError({"pass_at_m": [str(exc)]}) from exc
        return Response({"run": run.pk, "state": run.state, **run_report_json(report)})
