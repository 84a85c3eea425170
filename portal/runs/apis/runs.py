from __future__ import annotations

from typing import Any

from django.http import HttpResponse, StreamingHttpResponse
from django.shortcuts import get_object_or_404
from drf_spectacular.utils import OpenApiResponse, extend_schema, extend_schema_field
from rest_framework import serializers
from rest_framework.renderers import BaseRenderer
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from basestation.contract import DIRECTIONS, SAMPLE_COLUMNS, SampleColumn
from bookings.models import CALENDAR_SETUP
from core.api import Pagination, cached_json, paginated_data, request_user, valid_query
from core.openapi import errors
from portal.experiments.apis import SegmentOutput
from portal.runs import listing
from portal.runs.downloads import (
    run_package_response,
    samples_csv_response,
    samples_json_response,
    samples_parquet_response,
    series_parquet_response,
)
from portal.runs.models import RUNS, MeasurementSeries, Run
from portal.runs.provenance import provenance_view
from portal.runs.selectors import run_analysis_json, run_samples, runs_visible
from portal.runs.states import RunState

MAX_SAMPLES_PAGE = 10_000


def _run(request: Request, pk: int) -> Run:
    return get_object_or_404(runs_visible(user=request_user(request)), pk=pk)


class RunEventOutput(serializers.Serializer):
    from_state = serializers.CharField(help_text="Empty for the first event (the booking).")
    to_state = serializers.ChoiceField(choices=RunState.choices)
    at = serializers.DateTimeField()
    reason = serializers.CharField()


class MissingRangeOutput(serializers.Serializer):
    """Sequence numbers the run lacks; ``last_seq`` null: everything after ``first_seq``
    (the part of the program never recorded). Times in seconds since the run's start."""

    first_seq = serializers.IntegerField()
    last_seq = serializers.IntegerField(allow_null=True)
    from_s = serializers.FloatField(allow_null=True)
    to_s = serializers.FloatField(allow_null=True)


# How a run was made (``portal/runs/provenance.py``), as one inline schema: nested objects
# written out in place, not as components behind nullable references, which made the API
# docs page (Swagger UI) take several times as long to draw.
def _nullable(kind: str, description: str = "") -> dict[str, Any]:
    schema: dict[str, Any] = {"type": kind, "nullable": True}
    if description:
        schema["description"] = description
    return schema


def _object(properties: dict[str, Any], description: str = "") -> dict[str, Any]:
    schema = {
        "type": "object",
        "nullable": True,
        "required": list(properties),
        "properties": properties,
    }
    if description:
        schema["description"] = description
    return schema


_TEXT, _NUMBER, _INTEGER = _nullable("string"), _nullable("number"), _nullable("integer")
_RSSI = _object({"min": _NUMBER, "mean": _NUMBER, "max": _NUMBER})
_AGENT = _object(
    {
        "version": _TEXT,
        "resource": _TEXT,
        "interface": _nullable("string", "How the agent reaches the robot: radio, sim, …"),
        "control_hz": _nullable("number", "Commands per second."),
        "max_velocity_mps": _NUMBER,
        "max_accel_mps2": _NUMBER,
        "robot_hard_max_velocity_mps": _NUMBER,
        "robot_confirmed_limits": _nullable("boolean"),
        "low_battery_v": _NUMBER,
        "rail": _object(
            {
                "name": _TEXT,
                "file": _nullable("string", "Null: the agent's built-in rail."),
                "sha256": _nullable("string", "SHA-256 of the rail file's bytes."),
                "length_m": _NUMBER,
            }
        ),
    },
    "The base-station agent, as it described itself.",
)
_FIRMWARE = _object(
    {
        "build_id": _TEXT,
        "protocol_version": _INTEGER,
        "config": {
            "type": "object",
            "additionalProperties": {"type": "integer"},
            "description": "The compiled-in configuration; units in the names (mm_s, ms, 10mv).",
        },
    },
    "What the robot's firmware said of itself (its identity frame).",
)
_CLOCK = _object(
    {
        "synchronized": _nullable("boolean"),
        "offset_s": _nullable("number", "The NTP daemon's last offset."),
        "max_error_s": _NUMBER,
        "estimated_error_s": _NUMBER,
    },
    "The base station's clock as its kernel reported it.",
)
_LIMITS = _object({"max_velocity_mps": _NUMBER, "max_accel_mps2": _NUMBER})
_INSTANT = {"type": "string", "format": "date-time"}
RUN_PROVENANCE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "How the run was made, as recorded when it was staged and when it was "
    "collected (docs/run-package.md).",
    "required": ["format_version", "staged", "collected"],
    "properties": {
        "format_version": {"type": "integer"},
        "staged": _object(
            {
                "at": _INSTANT,
                "portal_version": {"type": "string"},
                "limits": {**_LIMITS, "description": "The limits sent with the run."},
                "agent": _AGENT,
                "firmware": _FIRMWARE,
            }
        ),
        "collected": _object(
            {
                "at": _INSTANT,
                "portal_version": {"type": "string"},
                "started_at": {**_INSTANT, "nullable": True},
                "ended_at": {**_INSTANT, "nullable": True},
                "agent": {**_AGENT, "description": "As the agent recorded it at the start."},
                "firmware": _FIRMWARE,
                "clock_at_start": _CLOCK,
                "clock_at_end": _CLOCK,
                "link": _object(
                    {
                        "exchanges": _INTEGER,
                        "answered": _INTEGER,
                        "lost": _INTEGER,
                        "loss_pct": _NUMBER,
                        "rssi_dbm": _RSSI,
                        "robot_rssi_dbm": _RSSI,
                    },
                    "The radio link over the run: one exchange per control tick.",
                ),
            }
        ),
    },
}


class RunOutput(serializers.ModelSerializer):
    reservation = serializers.IntegerField(source="reservation_id")
    resource = serializers.CharField(source="resource.name")
    owner = serializers.CharField(source="reservation.owner.username")
    segments = SegmentOutput(many=True)
    sample_count = serializers.SerializerMethodField(help_text="Samples stored in the portal.")
    events = RunEventOutput(many=True)
    missing = MissingRangeOutput(many=True, read_only=True)
    repeat_of = serializers.IntegerField(
        source="repeat_of_id", allow_null=True, help_text="The run this one repeats."
    )
    limits = serializers.SerializerMethodField()
    provenance = serializers.SerializerMethodField()

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
            "repeat_of",
            "limits",
            "provenance",
            "events",
        ]

    def get_sample_count(self, run: Run) -> int:
        return run.samples.count()

    @extend_schema_field(
        {**_LIMITS, "description": "Limits asked for at booking; null: the robot's."}
    )
    def get_limits(self, run: Run) -> dict[str, Any] | None:
        return run.limits

    @extend_schema_field(RUN_PROVENANCE_SCHEMA)
    def get_provenance(self, run: Run) -> dict[str, Any]:
        return provenance_view(run.provenance)


class RunFilter(serializers.Serializer):
    """The list's filters: the same as the My runs page (``portal/runs/listing.py``)."""

    state = serializers.ChoiceField(choices=RunState.choices, required=False)
    resource = serializers.SlugField(required=False, help_text="The robot's name.")
    experiment = serializers.IntegerField(required=False, min_value=1, help_text="Its id.")
    started_from = serializers.DateField(
        required=False, help_text="First day of start, in the testbed's time zone."
    )
    started_to = serializers.DateField(
        required=False, help_text="Last day of start (included), in the testbed's time zone."
    )
    q = serializers.CharField(
        required=False,
        max_length=200,
        help_text="Search: the run's or its experiment's title, the robot, or the run's number.",
    )

    def validate(self, attrs: dict[str, Any]) -> dict[str, Any]:
        first, last = attrs.get("started_from"), attrs.get("started_to")
        if first and last and last < first:
            raise serializers.ValidationError(
                {"started_to": ["The last day comes on or after the first."]}
            )
        return attrs


class RunListApi(APIView):
    pagination_class = Pagination

    @extend_schema(parameters=[RunFilter], responses=RunOutput(many=True))
    def get(self, request: Request) -> HttpResponse | Response:
        user = request_user(request)

        def listed() -> dict[str, Any]:
            query = valid_query(RunFilter, request.query_params)
            filters = listing.RunFilter(
                states=(query["state"],) if "state" in query else (),
                resource=query.get("resource", ""),
                experiment_id=query.get("experiment"),
                started_from=query.get("started_from"),
                started_to=query.get("started_to"),
                text=query.get("q", ""),
            )
            qs = listing.runs_filtered(user=user, filters=filters).prefetch_related("events")
            return paginated_data(request=request, queryset=qs, serializer_class=RunOutput)

        if "q" in request.query_params:
            # The search reads experiments' titles, which the runs' generation does not follow.
            return Response(listed())
        # A run carries its own period and state (a booking moved or cancelled writes its
        # run too); of the calendar it shows only resource names, which are the setup's: a
        # booking of a fixed node leaves its owner's runs list in the cache.
        return cached_json(
            request, (RUNS, CALENDAR_SETUP), (user.pk, user.is_testbed_admin), listed
        )


class RunDetailApi(APIView):
    @extend_schema(responses=RunOutput)
    def get(self, request: Request, pk: int) -> Response:
        run = _run(request, pk)
        return Response(RunOutput(run).data)


def _sample_field(column: SampleColumn) -> serializers.Field:
    """The API's field for one contract column (an ``epoch`` is given as a UTC instant)."""
    if column.choices is not None:  # the enum says it all: no description beside its $ref
        return serializers.ChoiceField(choices=column.choices, allow_null=column.nullable)
    common: dict[str, Any] = {"allow_null": column.nullable, "help_text": column.doc}
    if column.kind == "text":
        if column.max_length is not None:
            common["max_length"] = column.max_length
        return serializers.CharField(**common)
    if column.kind == "epoch":
        return serializers.DateTimeField(**common)
    if column.minimum is not None:
        common["min_value"] = int(column.minimum) if column.kind == "int" else column.minimum
    if column.kind == "int":
        return serializers.IntegerField(**common)
    return serializers.FloatField(**common)


class SampleOutput(serializers.Serializer):
    """One telemetry sample, as the robot's base station recorded it."""

    # The columns of ``basestation.contract.SAMPLE_COLUMNS``, in its order: written nowhere else.
    def get_fields(self) -> dict[str, serializers.Field]:
        return {column.name: _sample_field(column) for column in SAMPLE_COLUMNS}


class SamplesQuery(serializers.Serializer):
    after = serializers.IntegerField(
        min_value=0, default=0, help_text="Return samples with seq greater than this."
    )
    limit = serializers.IntegerField(
        min_value=1, max_value=MAX_SAMPLES_PAGE, default=1000, help_text="At most this many."
    )


class SamplesPageOutput(serializers.Serializer):
    run = serializers.IntegerField()
    state = serializers.ChoiceField(choices=RunState.choices)
    samples = SampleOutput(many=True, help_text="In seq order.")
    last_seq = serializers.IntegerField(
        min_value=0, help_text="The last seq in this page (`after` if empty): the next `after`."
    )


class RunSamplesApi(APIView):
    """One page of a run's samples, by sequence number (poll with `after=last_seq`)."""

    @extend_schema(parameters=[SamplesQuery], responses=SamplesPageOutput)
    def get(self, request: Request, pk: int) -> Response:
        run = _run(request, pk)
        query = valid_query(SamplesQuery, request.query_params)
        rows = list(run_samples(run=run, after_seq=query["after"], limit=query["limit"]))
        return Response(
            {
                "run": run.pk,
                "state": run.state,
                "samples": SampleOutput(rows, many=True).data,
                "last_seq": rows[-1].seq if rows else query["after"],
            }
        )


class SamplesDocumentOutput(serializers.Serializer):
    """The JSON download: the run's program and every sample."""

    run = serializers.IntegerField()
    title = serializers.CharField()
    resource = serializers.CharField()
    state = serializers.ChoiceField(choices=RunState.choices)
    segments = SegmentOutput(many=True)
    rail_length_m = serializers.FloatField(allow_null=True)
    samples = SampleOutput(many=True)


class StreamedRenderer(BaseRenderer):
    """Names a streamed download's media type for content negotiation; the view streams the
    body itself, and its errors are rendered as JSON (``DownloadApi``)."""

    def render(
        self, data: Any, accepted_media_type: str | None = None, renderer_context: Any = None
    ) -> bytes:
        raise NotImplementedError  # never reached: errors are rendered as JSON


class CsvRenderer(StreamedRenderer):
    media_type = "text/csv"
    format = "csv"


class ZipRenderer(StreamedRenderer):
    media_type = "application/zip"
    format = "zip"


class ParquetRenderer(StreamedRenderer):
    media_type = "application/vnd.apache.parquet"
    format = "parquet"


class DownloadApi(APIView):
    """A streamed download. Its errors are JSON whatever the client accepts."""

    def perform_content_negotiation(self, request: Request, force: bool = False) -> Any:
        renderer, media_type = super().perform_content_negotiation(request, force=True)
        if isinstance(renderer, StreamedRenderer):
            json_renderer = self.get_renderers()[0]
            return json_renderer, json_renderer.media_type
        return renderer, media_type


class RunSamplesCsvApi(DownloadApi):
    renderer_classes = [*APIView.renderer_classes, CsvRenderer]

    @extend_schema(
        responses={
            (200, "text/csv"): OpenApiResponse(
                str, description="Header line, then one line per sample in seq order."
            )
        }
    )
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        run = _run(request, pk)
        return samples_csv_response(request, run)


class RunSamplesJsonApi(DownloadApi):
    @extend_schema(responses={(200, "application/json"): SamplesDocumentOutput})
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        run = _run(request, pk)
        return samples_json_response(request, run)


class RunPackageApi(DownloadApi):
    """The run as one self-describing zip: `samples.csv`, `datapackage.json` (a Frictionless
    Data Package: the CSV's Table Schema with units, and under `amazing` the run, program,
    reservation, owner, provenance and analysis summary, with the format's version) and a
    `README.md` naming every column (docs/run-package.md)."""

    renderer_classes = [*APIView.renderer_classes, ZipRenderer]

    @extend_schema(
        responses={
            (200, "application/zip"): OpenApiResponse(
                bytes, description="README.md, samples.csv, then datapackage.json."
            )
        }
    )
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        run = _run(request, pk)
        return run_package_response(request, run)


class RunSamplesParquetApi(DownloadApi):
    """Every sample as one Parquet file: the contract's columns typed, `t` a UTC timestamp
    (docs/run-package.md)."""

    renderer_classes = [*APIView.renderer_classes, ParquetRenderer]

    @extend_schema(
        responses={
            (200, "application/vnd.apache.parquet"): OpenApiResponse(
                bytes, description="One row per sample in seq order."
            )
        }
    )
    def get(self, request: Request, pk: int) -> StreamingHttpResponse:
        return samples_parquet_response(request, _run(request, pk))


class MeasurementParquetApi(DownloadApi):
    """A measurement series placed on the robot's path, as one Parquet file: `t`, `t_base`,
    the values and the `robot_*` columns (docs/run-package.md)."""

    renderer_classes = [*APIView.renderer_classes, ParquetRenderer]

    @extend_schema(
        responses={
            (200, "application/vnd.apache.parquet"): OpenApiResponse(
                bytes, description="One row per time of the series, in time order."
            ),
            **errors(404),
        }
    )
    def get(self, request: Request, pk: int, name: str) -> StreamingHttpResponse:
        run = _run(request, pk)
        series = get_object_or_404(
            MeasurementSeries.objects.select_related("run"), run=run, name=name
        )
        return series_parquet_response(request, series)


class AnalysisQuery(serializers.Serializer):
    pass_at_m = serializers.FloatField(
        required=False,
        min_value=0,
        help_text="Where along the rail (m from its origin) to list passes; below the run's "
        "rail_length_m.",
    )


class GapOutput(serializers.Serializer):
    first_seq = serializers.IntegerField()
    last_seq = serializers.IntegerField()


class SegmentStatsOutput(serializers.Serializer):
    index = serializers.IntegerField(min_value=0)
    commanded_mps = serializers.FloatField(help_text="Signed: cw positive.")
    samples = serializers.IntegerField(min_value=0)
    start_s = serializers.FloatField()
    duration_s = serializers.FloatField()
    distance_m = serializers.FloatField()
    mean_mps = serializers.FloatField()
    min_mps = serializers.FloatField()
    max_mps = serializers.FloatField()
    std_mps = serializers.FloatField()
    mean_abs_error_mps = serializers.FloatField()
    battery_start_v = serializers.FloatField(allow_null=True)
    battery_end_v = serializers.FloatField(allow_null=True)
    battery_min_v = serializers.FloatField(allow_null=True)
    rtk_fixed_share = serializers.FloatField(min_value=0, max_value=1)


class LapOutput(serializers.Serializer):
    index = serializers.IntegerField()
    start_s = serializers.FloatField()
    end_s = serializers.FloatField()
    end_at = serializers.DateTimeField(allow_null=True)
    duration_s = serializers.FloatField()
    mean_speed_mps = serializers.FloatField()


class PassOutput(serializers.Serializer):
    index = serializers.IntegerField()
    t_s = serializers.FloatField()
    at = serializers.DateTimeField(allow_null=True)
    direction = serializers.ChoiceField(choices=DIRECTIONS)
    velocity_mps = serializers.FloatField()


class AnalysisOutput(serializers.Serializer):
    """Times as seconds since the first sample (``*_s``) and as UTC instants (``*_at``)."""

    run = serializers.IntegerField()
    state = serializers.ChoiceField(choices=RunState.choices)
    samples = serializers.IntegerField(min_value=0)
    missing = serializers.IntegerField(min_value=0)
    gaps = GapOutput(many=True)
    outside_program = serializers.IntegerField(min_value=0)
    first_at = serializers.DateTimeField(allow_null=True)
    duration_s = serializers.FloatField()
    rail_length_m = serializers.FloatField(allow_null=True)
    distance_m = serializers.FloatField(allow_null=True)
    mean_speed_mps = serializers.FloatField(allow_null=True)
    net_laps = serializers.IntegerField(allow_null=True)
    segments = SegmentStatsOutput(many=True)
    laps = LapOutput(many=True)
    pass_at_m = serializers.FloatField(allow_null=True)
    passes = PassOutput(many=True)


class RunAnalysisApi(APIView):
    """Per-segment statistics, laps, passes at a position and missing samples of a run."""

    @extend_schema(parameters=[AnalysisQuery], responses=AnalysisOutput)
    def get(self, request: Request, pk: int) -> Response:
        # Only what the kept answer's key reads (``run_analysis_json``), without the joined
        # booking, owner and resource: most calls are answered from the cache, and reading the
        # whole row took most of their time. A miss loads the rest of the run as it needs it.
        run = get_object_or_404(
            runs_visible(user=request_user(request))
            .select_related(None)
            .only("id", "created_at", "state", "last_seq", "rail_length_m"),
            pk=pk,
        )
        query = valid_query(AnalysisQuery, request.query_params)
        try:
            analysis = run_analysis_json(run=run, pass_at_m=query.get("pass_at_m"))
        except ValueError as exc:
            raise serializers.ValidationError({"pass_at_m": [str(exc)]}) from exc
        return Response({"run": run.pk, "state": run.state, **analysis})
