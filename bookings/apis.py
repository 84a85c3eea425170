from __future__ import annotations

from typing import Any

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from bookings.models import Reservation, Resource
from bookings.selectors import reservations_visible, resources_bookable
from bookings.services import reservation_cancel, reservation_create
from portal.experiments.selectors import experiments_visible


class ResourceOutput(serializers.ModelSerializer):
    class Meta:
        model = Resource
        fields = [
            "id",
            "name",
            "kind",
            "description",
            "max_velocity_mps",
            "max_accel_mps2",
            "enabled",
        ]


class ResourceListApi(APIView):
    @extend_schema(responses=ResourceOutput(many=True))
    def get(self, request: Request) -> Response:
        return Response(ResourceOutput(resources_bookable(), many=True).data)


class ReservationOutput(serializers.ModelSerializer):
    resource = serializers.CharField(source="resource.name")
    owner = serializers.CharField(source="owner.username")
    run = serializers.SerializerMethodField()

    class Meta:
        model = Reservation
        fields = ["id", "resource", "owner", "start_at", "end_at", "state", "run", "created_at"]

    def get_run(self, reservation: Reservation) -> dict[str, Any] | None:
        run = getattr(reservation, "run", None)
        return {"id": run.pk, "state": run.state} if run is not None else None


class ReservationInput(serializers.Serializer):
    resource = serializers.SlugRelatedField(slug_field="name", queryset=Resource.objects.all())
    start_at = serializers.DateTimeField()
    end_at = serializers.DateTimeField()
    experiment = serializers.IntegerField(required=False, allow_null=True)


class ReservationListApi(APIView):
    @extend_schema(responses=ReservationOutput(many=True))
    def get(self, request: Request) -> Response:
        qs = reservations_visible(user=request.user)  # type: ignore[arg-type]
        return Response(ReservationOutput(qs.order_by("-start_at")[:200], many=True).data)

    @extend_schema(request=ReservationInput, responses={201: ReservationOutput})
    def post(self, request: Request) -> Response:
        serializer = ReservationInput(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = dict(serializer.validated_data)
        experiment_id = data.pop("experiment", None)
        experiment = None
        if experiment_id is not None:
            experiment = get_object_or_404(
                experiments_visible(user=request.user),  # type: ignore[arg-type]
                pk=experiment_id,
            )
        reservation = reservation_create(owner=request.user, experiment=experiment, **data)  # type: ignore[arg-type]
        return Response(ReservationOutput(reservation).data, status=status.HTTP_201_CREATED)


class ReservationDetailApi(APIView):
    @extend_schema(responses=ReservationOutput)
    def get(self, request: Request, pk: int) -> Response:
        reservation = get_object_or_404(reservations_visible(user=request.user), pk=pk)  # type: ignore[arg-type]
        return Response(ReservationOutput(reservation).data)

    @extend_schema(responses=ReservationOutput)
    def delete(self, request: Request, pk: int) -> Response:
        reservation = get_object_or_404(reservations_visible(user=request.user), pk=pk)  # type: ignore[arg-type]
        reservation = reservation_cancel(reservation=reservation, by=request.user)  # type: ignore[arg-type]
        return Response(ReservationOutput(reservation).data)
