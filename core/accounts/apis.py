"""Who the API's caller is, and the API token a client signs in for (``amazing login``)."""

from __future__ import annotations

from typing import Any

from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.permissions import AllowAny, BasePermission, IsAuthenticated
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from core.accounts import services
from core.accounts.models import ApiToken
from core.accounts.services import TOKEN_EXPIRY_MAX_DAYS, TOKEN_NAME_MAX_LENGTH
from core.api import request_user
from core.audit.services import client_ip
from core.openapi import errors


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


class TokenSignInInput(serializers.Serializer):
    username = serializers.CharField(max_length=254, help_text="Username or email address.")
    password = serializers.CharField(max_length=4096, trim_whitespace=False)
    code = serializers.CharField(
        max_length=64,
        required=False,
        allow_blank=True,
        default="",
        help_text="The two-factor code (TOTP or a recovery code) of an account that has MFA.",
    )
    name = serializers.CharField(max_length=TOKEN_NAME_MAX_LENGTH, help_text="The token's name.")
    expires_in_days = serializers.IntegerField(
        min_value=1, max_value=TOKEN_EXPIRY_MAX_DAYS, required=False, allow_null=True, default=None
    )


class TokenOutput(serializers.Serializer):
    token = serializers.CharField(help_text="Shown this once: only its digest is kept.")
    name = serializers.CharField()
    username = serializers.CharField()
    expiry = serializers.DateTimeField(allow_null=True)


class ApiTokenApi(APIView):
    """POST: sign in with a password (and MFA code) for a new token; DELETE: revoke the
    token the request came with."""

    def get_permissions(self) -> list[BasePermission]:
        if self.request.method == "POST":
            return [AllowAny()]
        return [IsAuthenticated()]

    @extend_schema(
        auth=[],
        request=TokenSignInInput,
        responses={201: TokenOutput, **errors(400, 401, 403, 429)},
    )
    def post(self, request: Request) -> Response:
        given = TokenSignInInput(data=request.data)
        given.is_valid(raise_exception=True)
        data: dict[str, Any] = dict(given.validated_data)
        token, secret = services.api_token_sign_in(request=request._request, **data)
        return Response(
            {
                "token": secret,
                "name": token.name,
                "username": token.user.get_username(),
                "expiry": token.expiry,
            },
            status=status.HTTP_201_CREATED,
        )

    @extend_schema(responses={204: None, **errors(400, 401)})
    def delete(self, request: Request) -> Response:
        if not isinstance(request.auth, ApiToken):
            raise serializers.ValidationError("Only a request made with a token revokes it.")
        services.api_token_sign_out(
            user=request_user(request), token=request.auth, ip=client_ip(request)
        )
        return Response(status=status.HTTP_204_NO_CONTENT)
