from __future__ import annotations

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from basestation.contract import DIRECTIONS, MAX_PROGRAM_S, MAX_SEGMENTS, MAX_TITLE_CHARS
from portal.api import GreaterThan, Pagination, paginated_response, request_user, valid_input
from portal.experiments.models import Experiment
from portal.experiments.selectors import experiments_visible
from portal.experiments.services import experiment_create, experiment_update
from portal.openapi import ClosedSerializer


class SegmentOutput(serializers.Serializer):
    velocity_mps = serializers.FloatField(min_value=0)
    direction = serializers.ChoiceField(choices=DIRECTIONS)
    duration_s = serializers.FloatField(validators=[GreaterThan(0)])


class SegmentInput(ClosedSerializer):
    """One step of a program: hold a velocity in a direction for a duration."""

    velocity_mps = serializers.FloatField(
        min_value=0,
        help_text="m/s, at most the max_velocity_mps of the robot it will run on "
        "(checked against the fastest robot when written, and the booked one at booking).",
    )
    direction = serializers.ChoiceField(
        choices=DIRECTIONS, help_text="cw increases the position along the rail."
    )
    duration_s = serializers.FloatField(max_value=MAX_PROGRAM_S, validators=[GreaterThan(0)])


class ExperimentOutput(serializers.ModelSerializer):
    segments = SegmentOutput(many=True)
    duration_s = serializers.FloatField(read_only=True)
    owner = serializers.CharField(source="owner.username")

    class Meta:
        model = Experiment
        fields = ["id", "title", "segments", "duration_s", "owner", "created_at", "updated_at"]


class ExperimentInput(serializers.Serializer):
    title = serializers.CharField(max_length=MAX_TITLE_CHARS)
    # The service checks them again: the robots' limits and the program's total length.
    segments = serializers.ListField(
        child=SegmentInput(),
        min_length=1,
        max_length=MAX_SEGMENTS,
        help_text=f"The program, in order; at most {MAX_PROGRAM_S:g} s in all.",
    )


class ExperimentListApi(APIView):
    pagination_class = Pagination

    @extend_schema(responses=ExperimentOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = experiments_visible(user=request_user(request)).order_by("-created_at", "-pk")
        return paginated_response(
            request=request, view=self, queryset=qs, serializer_class=ExperimentOutput
        )

    @extend_schema(request=ExperimentInput, responses={201: ExperimentOutput})
    def post(self, request: Request) -> Response:
        data = valid_input(ExperimentInput, request.data)
        experiment = experiment_create(owner=request_user(request), **data)
        return Response(ExperimentOutput(experiment).data, status=status.HTTP_201_CREATED)


class ExperimentDetailApi(APIView):
    def _get(self, request: Request, pk: int) -> Experiment:
        return get_object_or_404(experiments_visible(user=request_user(request)), pk=pk)

    @extend_schema(responses=ExperimentOutput)
    def get(self, request: Request, pk: int) -> Response:
        return Response(ExperimentOutput(self._get(request, pk)).data)

    @extend_schema(request=ExperimentInput, responses=ExperimentOutput)
    def put(self, request: Request, pk: int) -> Response:
        experiment = self._get(request, pk)
        data = valid_input(ExperimentInput, request.data)
        return Response(ExperimentOutput(experiment_update(experiment=experiment, **data)).data)
