from __future__ import annotations

from django.http import StreamingHttpResponse
from django.shortcuts import get_object_or_404
from drf_spectacular.utils import OpenApiParameter, extend_schema
from rest_framework import serializers
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from portal.api import request_user, valid_input
from portal.experiments.apis import SegmentSerializer
from portal.runs.downloads import is_asgi, samples_csv_response, samples_json_response
from portal.runs.models import Run
from portal.runs.selectors import run_report, run_report_json, run_samples, runs_visible


def _run(request: Request, pk: int) -> Run:
    return get_object_or_404(runs_visible(user=request_user(request)), pk=pk)


class RunEventOutput(serializers.Serializer):
    from_state = serializers.CharField()
    to_state = serializers.CharField()
    at = serializers.DateTimeField()
    reason = serializers.CharField()


class MissingRangeOutput(serializers.Serializer):
    """Sequence numbers the run lacks; ``last_seq`` null: everything after ``first_seq``
    (the part of the program never recorded). Times in seconds since the run's start."""

    first_seq = serializers.IntegerField()
    last_seq = serializers.IntegerField(allow_null=True)
    from_s = serializers.FloatField(allow_null=True)
    to_s = serializers.FloatField(allow_null=True)


class RunOutput(serializers.ModelSerializer):
    reservation = serializers.IntegerField(source="reservation_id")
    resource = serializers.CharField(source="resource.name")
    owner = serializers.CharField(source="reservation.owner.username")
    segments = SegmentSerializer(many=True)
    sample_count = serializers.SerializerMethodField()
    events = RunEventOutput(many=True)
    missing = MissingRangeOutput(many=True, read_only=True)

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
            "missing",
            "events",
        ]

    def get_sample_count(self, run: Run) -> int:
        return run.samples.count()


class RunListApi(APIView):
    @extend_schema(responses=RunOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = runs_visible(user=request_user(request)).prefetch_related("events")
        state = request.query_params.get("state")
        if state:
            qs = qs.filter(state=state)
        return Response(RunOutput(qs[:200], many=True).data)


class RunDetailApi(APIView):
    @extend_schema(responses=RunOutput)
    def get(self, request: Request, pk: int) -> Response:
        run = _run(request, pk)
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
        run = _run(request, pk)
        query = valid_input(SamplesQuery, request.query_params)
        rows = list(run_samples(run=run, after_seq=query["after"], limit=query["limit"]))
        return Response(
            {
                "run": run.pk,
                "state": run.state,
                "samples": SampleOutput(rows, many=True).data,
                "last_seq": rows[-1].seq if rows else query["after"],
            }
        )


class RunSamplesCsvApi(APIView):
    @extend_schema(responses={(200, "text/csv"): str})
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        run = _run(request, pk)
        return samples_csv_response(run, asynchronous=is_asgi(request))


class RunSamplesJsonApi(APIView):
    @extend_schema(responses={(200, "application/json"): dict})
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        run = _run(request, pk)
        return samples_json_response(run, asynchronous=is_asgi(request))


class AnalysisQuery(serializers.Serializer):
    pass_at_m = serializers.FloatField(
        required=False, help_text="Where along the rail (m from its origin) to list passes."
    )


class RunAnalysisApi(APIView):
    """Per-segment statistics, laps, passes at a position and missing samples of a run."""

    @extend_schema(parameters=[AnalysisQuery], responses={200: dict})
    def get(self, request: Request, pk: int) -> Response:
        run = _run(request, pk)
        query = valid_input(AnalysisQuery, request.query_params)
        try:
            report = run_report(run=run, pass_at_m=query.get("pass_at_m"))
        except ValueError as exc:
            raise serializers.ValidationError({"pass_at_m": [str(exc)]}) from exc
        return Response({"run": run.pk, "state": run.state, **run_report_json(report)})
