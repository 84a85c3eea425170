"""The audit log over the API, for admins: who did what, when, from where and why."""

from __future__ import annotations

from drf_spectacular.utils import extend_schema
from rest_framework import serializers
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from core.accounts.permissions import StaffVerified
from core.api import DateTimeInput, Pagination, paginated_response, valid_query
from core.audit.models import AuditEvent


class AuditEventOutput(serializers.ModelSerializer):
    actor = serializers.CharField(source="actor_name", help_text="Username, or `system`.")
    details = serializers.DictField(source="data", help_text="What it changed or was given.")

    class Meta:
        model = AuditEvent
        fields = [
            "id",
            "at",
            "actor",
            "action",
            "target_type",
            "target_id",
            "ip",
            "reason",
            "details",
        ]


class AuditFilter(serializers.Serializer):
    action = serializers.CharField(required=False, help_text="e.g. `reservation.create`.")
    actor = serializers.CharField(required=False, help_text="Username.")
    target_type = serializers.CharField(required=False, help_text="e.g. `bookings.reservation`.")
    target_id = serializers.CharField(required=False)
    since = DateTimeInput(required=False, help_text="Events at or after this instant.")
    until = DateTimeInput(required=False, help_text="Events before this instant.")


class AuditEventListApi(APIView):
    """Newest first."""

    permission_classes = [StaffVerified]
    pagination_class = Pagination

    @extend_schema(parameters=[AuditFilter], responses=AuditEventOutput(many=True))
    def get(self, request: Request) -> Response:
        query = valid_query(AuditFilter, request.query_params)
        qs = AuditEvent.objects.order_by("-at", "-pk")
        if "action" in query:
            qs = qs.filter(action=query["action"])
        if "actor" in query:
            qs = qs.filter(actor_name=query["actor"])
        if "target_type" in query:
            qs = qs.filter(target_type=query["target_type"])
        if "target_id" in query:
            qs = qs.filter(target_id=query["target_id"])
        if "since" in query:
            qs = qs.filter(at__gte=query["since"])
        if "until" in query:
            qs = qs.filter(at__lt=query["until"])
        return paginated_response(
            request=request, view=self, queryset=qs, serializer_class=AuditEventOutput
        )
