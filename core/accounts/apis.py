"""Who the API's caller is: for clients to check their token (``amazing login``)."""

from __future__ import annotations

from drf_spectacular.utils import extend_schema
from rest_framework import serializers
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from core.api import request_user


class MeOutput(serializers.Serializer):
    username = serializers.CharField()
    email = serializers.CharField(allow_blank=True)
    is_admin = serializers.BooleanField(help_text="A testbed admin: sees and decides everything.")


class MeApi(APIView):
    @extend_schema(responses=MeOutput)
    def get(self, request: Request) -> Response:
        user = request_user(request)
        return Response(
            {"username": user.username, "email": user.email, "is_admin": user.is_testbed_admin}
        )
