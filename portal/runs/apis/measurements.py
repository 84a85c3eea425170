"""A run's measurement series through the REST API: upload a file, send batches during the
run, read the series placed on the path, set a clock offset, delete. Every call is
``portal.runs.measurements``'s, for the run's owner and staff (``runs_visible``)."""

from __future__ import annotations

from typing import Any

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.parsers import JSONParser, MultiPartParser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from core.api import DateTimeInput, request_user, valid_input
from core.audit.services import client_ip
from core.errors import DomainError
from core.openapi import ClosedSerializer, errors
from portal.runs import measurements
from portal.runs.apis.reservations import request_door
from portal.runs.measurement_files import FORMATS, format_of
from portal.runs.models import MeasurementSeries, Run
from portal.runs.selectors import runs_visible

# Points one batch may carry: a second of per-packet readings is a few hundred; more come as
# more batches (each answered within a request's time, its summary made again).
BATCH_MAX_POINTS = 1000


class TooLarge(DomainError):
    http_status = 413
    code = "request_entity_too_large"


def _run(request: Request, pk: int) -> Run:
    return get_object_or_404(runs_visible(user=request_user(request)), pk=pk)


def _series(request: Request, pk: int, name: str) -> MeasurementSeries:
    run = _run(request, pk)
    return get_object_or_404(MeasurementSeries.objects.select_related("run"), run=run, name=name)


def _door(request: Request) -> dict[str, Any]:
    return {"ip": client_ip(request), "via": str(request_door(request))}


class SeriesOutput(serializers.ModelSerializer):
    summary = serializers.JSONField(
        help_text="The series placed on the run's path, per value column: where the points "
        "fell (placed, before, after, gap), their statistics, per metre and per grid cell, "
        "and downsampled lines (docs/measurements.md)."
    )

    class Meta:
        model = MeasurementSeries
        fields = [
            "name",
            "unit",
            "description",
            "source_node",
            "columns",
            "clock_offset_s",
            "marker_at",
            "point_count",
            "summary",
            "created_at",
            "updated_at",
        ]


class AddedOutput(serializers.Serializer):
    series = SeriesOutput()
    stored = serializers.IntegerField(help_text="Values new to the series.")
    already = serializers.IntegerField(help_text="Values it held already (sent again).")


class UploadInput(serializers.Serializer):
    file = serializers.FileField(help_text="CSV, JSON or Parquet: a time column and values.")
    name = serializers.CharField(max_length=64, help_text="The series's name (a slug).")
    format = serializers.ChoiceField(
        choices=FORMATS, required=False, help_text="By default, the file name's extension."
    )
    unit = serializers.CharField(max_length=32, required=False, allow_blank=True)
    description = serializers.CharField(max_length=2000, required=False, allow_blank=True)
    source_node = serializers.CharField(max_length=64, required=False, allow_blank=True)
    time_column = serializers.CharField(max_length=64, required=False, allow_blank=True)
    columns = serializers.CharField(
        max_length=1000,
        required=False,
        allow_blank=True,
        help_text="Value columns, comma-separated; by default every other column.",
    )
    clock_offset_s = serializers.FloatField(required=False, help_text="Added to the file's times.")
    marker_at = DateTimeInput(
        required=False,
        help_text="When the measuring machine saw the robot's first segment begin, on its clock.",
    )


class BatchInput(ClosedSerializer):
    points = serializers.ListField(
        child=serializers.DictField(),
        min_length=1,
        max_length=BATCH_MAX_POINTS,
        help_text='Points as objects: {"t": RFC 3339 or Unix seconds, "<column>": number}.',
    )
    unit = serializers.CharField(max_length=32, required=False, allow_blank=True)
    description = serializers.CharField(max_length=2000, required=False, allow_blank=True)
    source_node = serializers.CharField(max_length=64, required=False, allow_blank=True)


class ChangeInput(ClosedSerializer):
    clock_offset_s = serializers.FloatField(
        required=False, help_text="Added to every point's time (seconds, within ±86400)."
    )
    marker_at = DateTimeInput(
        required=False,
        help_text="When the measuring machine saw the robot's first segment begin, on its own "
        "clock: the summary's `suggested_offset_s` then aligns the two.",
    )


def _added(result: measurements.Added) -> Response:
    return Response(
        AddedOutput(result).data,
        status=status.HTTP_201_CREATED if result.created else status.HTTP_200_OK,
    )


class MeasurementListApi(APIView):
    """A run's measurement series; a file uploaded as one (made, or added to)."""

    parser_classes = [MultiPartParser]

    @extend_schema(responses={200: SeriesOutput(many=True), **errors(404)})
    def get(self, request: Request, pk: int) -> Response:
        run = _run(request, pk)
        return Response(SeriesOutput(run.measurements.order_by("name"), many=True).data)

    @extend_schema(
        operation_id="api_v1_runs_measurements_upload",
        request={"multipart/form-data": UploadInput},
        responses={
            201: AddedOutput,
            200: AddedOutput,
            **errors(400, 404, 413, e413="The file is larger than MEASUREMENT_MAX_UPLOAD_BYTES."),
        },
    )
    def post(self, request: Request, pk: int) -> Response:
        run = _run(request, pk)
        # Said before the body is read: a 1 GB file is refused, not written to disk first.
        declared = int(request.META.get("CONTENT_LENGTH") or 0)
        limit = measurements.max_upload_bytes()
        if declared > limit:
            raise TooLarge(f"the file is larger than {limit} bytes (MEASUREMENT_MAX_UPLOAD_BYTES)")
        # A form's fields and its file, as one object (``valid_input`` reads a form's
        # QueryDict as no JSON body).
        data = valid_input(UploadInput, {**request.POST.dict(), **request.FILES.dict()})
        upload = data["file"]
        if upload.size > limit:
            raise TooLarge(f"the file is larger than {limit} bytes (MEASUREMENT_MAX_UPLOAD_BYTES)")
        columns = [c.strip() for c in data.get("columns", "").split(",") if c.strip()]
        try:
            fmt = format_of(upload.name or "", data.get("format", ""))
        except ValueError as exc:
            raise measurements.MeasurementRefused(str(exc), fields={"format": [str(exc)]}) from None
        points = measurements.read_file_points(
            upload.read(), fmt, time_column=data.get("time_column", ""), columns=columns
        )
        return _added(
            measurements.measurement_add(
                run=run,
                by=request_user(request),
                name=data["name"],
                points=points,
                unit=data.get("unit", ""),
                description=data.get("description", ""),
                source_node=data.get("source_node", ""),
                clock_offset_s=data.get("clock_offset_s"),
                marker_at=data.get("marker_at"),
                **_door(request),
            )
        )


class MeasurementApi(APIView):
    """One series: read it, send it a batch of points (during the run too), set its clock
    offset, delete it."""

    parser_classes = [JSONParser]

    @extend_schema(responses={200: SeriesOutput, **errors(404)})
    def get(self, request: Request, pk: int, name: str) -> Response:
        return Response(SeriesOutput(_series(request, pk, name)).data)

    @extend_schema(
        operation_id="api_v1_runs_measurements_points_add",
        request=BatchInput,
        responses={201: AddedOutput, 200: AddedOutput, **errors(400, 404)},
    )
    def post(self, request: Request, pk: int, name: str) -> Response:
        run = _run(request, pk)
        data = valid_input(BatchInput, request.data)
        points = measurements.rows_points(data["points"])
        return _added(
            measurements.measurement_add(
                run=run,
                by=request_user(request),
                name=name,
                points=points,
                unit=data.get("unit", ""),
                description=data.get("description", ""),
                source_node=data.get("source_node", ""),
                **_door(request),
            )
        )

    @extend_schema(request=ChangeInput, responses={200: SeriesOutput, **errors(400, 404)})
    def patch(self, request: Request, pk: int, name: str) -> Response:
        series = _series(request, pk, name)
        data = valid_input(ChangeInput, request.data)
        updated = measurements.measurement_update(
            series=series,
            by=request_user(request),
            clock_offset_s=data.get("clock_offset_s"),
            marker_at=data.get("marker_at"),
            **_door(request),
        )
        return Response(SeriesOutput(updated).data)

    @extend_schema(request=None, responses={204: None, **errors(404)})
    def delete(self, request: Request, pk: int, name: str) -> Response:
        series = _series(request, pk, name)
        measurements.measurement_delete(series=series, by=request_user(request), **_door(request))
        return Response(status=status.HTTP_204_NO_CONTENT)


__all__ = ["MeasurementApi", "MeasurementListApi"]
