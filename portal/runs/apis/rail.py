"""A robot's rail for maps of the roof (``portal/runs/roof.py``), for every signed-in user:
the run pages of experimenters show it."""

from __future__ import annotations

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers
from rest_framework.permissions import IsAuthenticated
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.models import Resource
from core.openapi import errors
from portal.runs.roof import rail_drawing


class RailOutput(serializers.Serializer):
    geometry = serializers.BooleanField(
        help_text="False for a robot without a rail geometry: only `length_m` is known."
    )
    length_m = serializers.FloatField()
    name = serializers.CharField(required=False)
    centre = serializers.DictField(required=False, help_text="{lat, lon} of the map's origin.")
    grid_points = serializers.IntegerField(required=False)
    origin = serializers.DictField(required=False, help_text="{x_m, y_m} where track_m is 0.")
    points = serializers.ListField(
        child=serializers.DictField(),
        required=False,
        help_text="The corners clockwise: {x_m east, y_m north of the centre, track_m}.",
    )
    cells = serializers.ListField(
        child=serializers.DictField(),
        required=False,
        help_text="The thesis grid cells as spans of track_m: {id, from_m, to_m}.",
    )
    nodes = serializers.ListField(
        child=serializers.DictField(),
        required=False,
        help_text="The fixed nodes' places: {name, lat, lon, x_m, y_m}.",
    )


class RailApi(APIView):
    permission_classes = [IsAuthenticated]

    @extend_schema(
        responses={
            200: RailOutput,
            **errors(400, 503, e400="The resource is not a mobile node (field `resource`)."),
        }
    )
    def get(self, request: Request, name: str) -> Response:
        return Response(rail_drawing(resource=get_object_or_404(Resource, name=name)))
