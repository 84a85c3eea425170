from __future__ import annotations

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from basestation.contract import DIRECTIONS
from portal.api import request_user, valid_input
from portal.experiments.models import Experiment
from portal.experiments.selectors import experiments_visible
from portal.experiments.services import experiment_create, experiment_update


class SegmentSerializer(serializers.Serializer):
    velocity_mps = serializers.FloatField(min_value=0)
    direction = serializers.ChoiceField(choices=DIRECTIONS)
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
        qs = experiments_visible(user=request_user(request))
        return Response(ExperimentOutput(qs, many=True).data)

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
