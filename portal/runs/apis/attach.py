"""Attach an experiment to a booking made through the lease API (it holds its robot without
a program until its owner gives it one, before it starts)."""

from __future__ import annotations

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from core.api import request_user, valid_input
from core.audit.idempotency import idempotent
from core.audit.services import client_ip
from core.openapi import errors
from portal.experiments.selectors import experiments_visible
from portal.runs.apis.reservations import ReservationOutput, request_door
from portal.runs.selectors import reservations_with_runs_visible
from portal.runs.services import reservations as with_run


class AttachInput(serializers.Serializer):
    experiment = serializers.IntegerField(help_text="One of your experiments.")


class ReservationAttachApi(APIView):
    """The booking's robot runs ``experiment`` in it: its run is made (`scheduled`).

    Only for a booking made through the testbed scheduler's lease API, by its owner, before
    it starts; the experiment is checked as booking checks one (the robot's limits, the
    booking's length) and every other booking rule applies again."""

    @extend_schema(
        request=AttachInput,
        responses={
            201: ReservationOutput,
            **errors(
                400,
                403,
                404,
                409,
                e400="The experiment does not fit the robot or the booking.",
                e403="Not the booking's owner, or not their experiment.",
                e404="The booking or the experiment is not found.",
                e409="The booking has its experiment already, has started, or was not made "
                "through the lease API; or a booking rule refuses it now.",
            ),
        },
    )
    @idempotent
    def post(self, request: Request, pk: int) -> Response:
        user = request_user(request)
        reservation = get_object_or_404(reservations_with_runs_visible(user=user), pk=pk)
        data = valid_input(AttachInput, request.data)
        experiment = get_object_or_404(experiments_visible(user=user), pk=data["experiment"])
        with_run.reservation_attach(
            reservation=reservation,
            experiment=experiment,
            by=user,
            ip=client_ip(request),
            via=request_door(request),
        )
        attached = reservations_with_runs_visible(user=user).get(pk=reservation.pk)
        return Response(ReservationOutput(attached).data, status=status.HTTP_201_CREATED)
