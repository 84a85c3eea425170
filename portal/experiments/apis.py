from __future__ import annotations

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema, extend_schema_field
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from basestation.contract import DIRECTIONS, MAX_PROGRAM_S, MAX_SEGMENTS, MAX_TITLE_CHARS
from bookings.models import Resource
from bookings.selectors import mobiles_bookable
from core.api import GreaterThan, Pagination, paginated_response, request_user, valid_input
from core.openapi import ClosedSerializer
from portal.experiments.models import Experiment
from portal.experiments.selectors import experiment_fits, experiments_visible
from portal.experiments.services import experiment_create, experiment_update


class SegmentOutput(serializers.Serializer):
    velocity_mps = serializers.FloatField(min_value=0)
    direction = serializers.ChoiceField(choices=DIRECTIONS)
    duration_s = serializers.FloatField(validators=[GreaterThan(0)])


class SegmentInput(ClosedSerializer):
    """One step of a program: hold a velocity in a direction for a duration."""

    velocity_mps = serializers.FloatField(
        min_value=0,
        help_text="m/s, at most the limit of the robot it will run on: the stricter of the "
        "portal's max_velocity_mps and the one its base station reports. When written, the "
        "program must fit at least one robot you may book; booking checks the booked one.",
    )
    direction = serializers.ChoiceField(
        choices=DIRECTIONS, help_text="cw increases the position along the rail."
    )
    duration_s = serializers.FloatField(max_value=MAX_PROGRAM_S, validators=[GreaterThan(0)])


class RobotFitOutput(serializers.Serializer):
    """Whether the program fits one robot the author may book."""

    name = serializers.CharField()
    fits = serializers.BooleanField()
    max_velocity_mps = serializers.FloatField(help_text="The robot's limit, m/s.")
    limited_by = serializers.ChoiceField(
        choices=["portal", "agent"],
        help_text="Whose limit it is: the portal's for the resource, or the lower one its "
        "base station (agent) reports.",
    )


class ExperimentOutput(serializers.ModelSerializer):
    segments = SegmentOutput(many=True)
    duration_s = serializers.FloatField(read_only=True)
    owner = serializers.CharField(source="owner.username")
    robots = serializers.SerializerMethodField(
        help_text="Each robot you may book, and whether this program fits its limit."
    )

    _robots: list[Resource] | None = None

    class Meta:
        model = Experiment
        fields = [
            "id",
            "title",
            "segments",
            "duration_s",
            "owner",
            "robots",
            "created_at",
            "updated_at",
        ]

    @extend_schema_field(RobotFitOutput(many=True))
    def get_robots(self, experiment: Experiment) -> list[dict[str, object]]:
        # A page of experiments shares one serializer: the robots are read once for it.
        if self._robots is None:
            self._robots = mobiles_bookable()
        fits = experiment_fits(experiment, self._robots)
        return [
            {
                "name": fit.limit.resource,
                "fits": fit.fits,
                "max_velocity_mps": fit.limit.mps,
                "limited_by": fit.limit.source,
            }
            for fit in fits
        ]


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
