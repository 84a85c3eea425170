"""``GET /api/v1/events/``: a user's own events in order, for scripts without a public URL."""

from __future__ import annotations

from drf_spectacular.utils import extend_schema, extend_schema_field
from rest_framework import serializers
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from core.api import request_user, valid_query
from core.events.catalogue import EVENT_TYPES, PAYLOADS
from core.events.selectors import LIMIT_MAX, WAIT_MAX_S, events_wait


class EventQuery(serializers.Serializer):
    after = serializers.IntegerField(
        min_value=0, default=0, help_text="The `id` of the last event seen; 0 for the oldest."
    )
    wait = serializers.FloatField(
        min_value=0,
        max_value=WAIT_MAX_S,
        default=0,
        help_text=f"Seconds to wait for an event when there is none yet (at most {WAIT_MAX_S:g}).",
    )
    limit = serializers.IntegerField(min_value=1, max_value=LIMIT_MAX, default=100)
    type = serializers.MultipleChoiceField(
        choices=sorted(EVENT_TYPES),
        required=False,
        help_text="Only these types (repeat the parameter for several).",
    )
    subject = serializers.CharField(
        required=False,
        max_length=80,
        help_text="Only the events about this: `run:17`, `reservation:42`.",
    )


@extend_schema_field(
    {
        "oneOf": [{"$ref": f"#/components/schemas/{name}"} for name in PAYLOADS],
        "description": "The payload, shaped by the event's type and version.",
    }
)
class EventData(serializers.DictField):
    """An event's payload: one of the catalogue's shapes (core/events/catalogue.py)."""


class EventOutput(serializers.Serializer):
    id = serializers.IntegerField(
        source="position", help_text="Its place in the order of all events."
    )
    type = serializers.CharField()
    version = serializers.IntegerField(help_text="The version of the payload's shape.")
    subject = serializers.CharField(help_text="What it is about: `reservation:42`, `run:17`.")
    seq = serializers.IntegerField(help_text="The subject's own count: 1 for its first event.")
    occurred_at = serializers.DateTimeField()

    def get_fields(self) -> dict[str, serializers.Field]:
        fields = super().get_fields()
        # "data", as Standard Webhooks' envelope names it; a class attribute of that name would
        # hide the serializer's own ``data``.
        fields["data"] = EventData(source="payload")
        return fields


class EventPage(serializers.Serializer):
    events = EventOutput(many=True)
    last = serializers.IntegerField(help_text="Pass as `after` to ask for what comes next.")


class EventListApi(APIView):
    """Your events, oldest first, from `after` on; with `wait`, a long poll that answers as
    soon as there is one. Staff (with their second factor) also get the events of no one's."""

    @extend_schema(parameters=[EventQuery], responses=EventPage)
    def get(self, request: Request) -> Response:
        query = valid_query(EventQuery, request.query_params)
        events = events_wait(
            user=request_user(request),
            after=query["after"],
            limit=query["limit"],
            wait_s=query["wait"],
            types=sorted(query.get("type") or []),
            subject=query.get("subject"),
        )
        last = events[-1].position if events else query["after"]
        return Response({"events": EventOutput(events, many=True).data, "last": last})
