"""``/api/v1/webhooks/``: a user's webhooks, each one's delivery log, a test event, a resume."""

from __future__ import annotations

from django.shortcuts import get_object_or_404
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from core.api import Pagination, paginated_response, request_user, valid_input
from core.audit.services import client_ip
from core.events.catalogue import EVENT_TYPES
from core.webhooks import services
from core.webhooks.delivery import webhook_message_id
from core.webhooks.models import WebhookDelivery, WebhookSubscription
from core.webhooks.selectors import webhook_deliveries, webhooks_visible


class WebhookOutput(serializers.ModelSerializer):
    paused = serializers.SerializerMethodField()

    class Meta:
        model = WebhookSubscription
        fields = [
            "id",
            "url",
            "description",
            "types",
            "staff_events",
            "created_at",
            "paused",
            "paused_at",
            "pause_reason",
        ]

    def get_paused(self, subscription: WebhookSubscription) -> bool:
        return subscription.paused_at is not None


class WebhookCreated(WebhookOutput):
    secret = serializers.SerializerMethodField(
        help_text="Verifies the signatures (Standard Webhooks' `whsec_…`): shown this once."
    )

    class Meta(WebhookOutput.Meta):
        fields = [*WebhookOutput.Meta.fields, "secret"]

    def get_secret(self, subscription: WebhookSubscription) -> str:
        return str(self.context["secret"])


class WebhookInput(serializers.Serializer):
    url = serializers.URLField(
        max_length=500, help_text="https, and a public address (the portal checks it)."
    )
    description = serializers.CharField(max_length=200, required=False, default="")
    types = serializers.ListField(
        child=serializers.ChoiceField(choices=sorted(EVENT_TYPES)),
        required=False,
        default=list,
        max_length=len(EVENT_TYPES),
        help_text="Only these event types; none for all of yours.",
    )
    staff_events = serializers.BooleanField(
        required=False,
        default=False,
        help_text="Also the events of no one (robots, the scheduler link): staff only.",
    )


class WebhookChange(serializers.Serializer):
    url = serializers.URLField(max_length=500, required=False)
    description = serializers.CharField(max_length=200, required=False)
    types = serializers.ListField(
        child=serializers.ChoiceField(choices=sorted(EVENT_TYPES)),
        required=False,
        max_length=len(EVENT_TYPES),
    )


class DeliveryOutput(serializers.ModelSerializer):
    event = serializers.IntegerField(source="event.position", help_text="The event's `id`.")
    type = serializers.CharField(source="event.type")
    webhook_id = serializers.SerializerMethodField(help_text="Its `webhook-id` header.")

    class Meta:
        model = WebhookDelivery
        fields = [
            "id",
            "event",
            "type",
            "webhook_id",
            "state",
            "attempts",
            "created_at",
            "last_tried_at",
            "last_status",
            "last_error",
            "next_try_at",
            "delivered_at",
        ]

    def get_webhook_id(self, delivery: WebhookDelivery) -> str:
        return webhook_message_id(delivery.event)


class TestSent(serializers.Serializer):
    event = serializers.IntegerField(help_text="The test event's id (`webhook.test`).")


def _mine(request: Request, pk: int) -> WebhookSubscription:
    return get_object_or_404(webhooks_visible(user=request_user(request)), pk=pk)


class WebhookListApi(APIView):
    """Your webhooks: each is sent your events (of the types it asks for), signed."""

    pagination_class = Pagination

    @extend_schema(responses=WebhookOutput(many=True))
    def get(self, request: Request) -> Response:
        return paginated_response(
            request=request,
            view=self,
            queryset=webhooks_visible(user=request_user(request)),
            serializer_class=WebhookOutput,
        )

    @extend_schema(request=WebhookInput, responses={201: WebhookCreated})
    def post(self, request: Request) -> Response:
        data = valid_input(WebhookInput, request.data)
        subscription, secret = services.webhook_create(
            owner=request_user(request), ip=client_ip(request), **data
        )
        return Response(
            WebhookCreated(subscription, context={"secret": secret}).data,
            status=status.HTTP_201_CREATED,
        )


class WebhookDetailApi(APIView):
    @extend_schema(responses=WebhookOutput)
    def get(self, request: Request, pk: int) -> Response:
        return Response(WebhookOutput(_mine(request, pk)).data)

    @extend_schema(request=WebhookChange, responses=WebhookOutput)
    def patch(self, request: Request, pk: int) -> Response:
        subscription = _mine(request, pk)
        data = valid_input(WebhookChange, request.data)
        changed = services.webhook_update(
            subscription=subscription, by=request_user(request), ip=client_ip(request), **data
        )
        return Response(WebhookOutput(changed).data)

    @extend_schema(responses={204: None})
    def delete(self, request: Request, pk: int) -> Response:
        services.webhook_delete(
            subscription=_mine(request, pk), by=request_user(request), ip=client_ip(request)
        )
        return Response(status=status.HTTP_204_NO_CONTENT)


class WebhookResumeApi(APIView):
    """Send to it again: what failed first, then what waited behind it, in order."""

    @extend_schema(request=None, responses=WebhookOutput)
    def post(self, request: Request, pk: int) -> Response:
        resumed = services.webhook_resume(
            subscription=_mine(request, pk), by=request_user(request), ip=client_ip(request)
        )
        return Response(WebhookOutput(resumed).data)


class WebhookTestApi(APIView):
    """A `webhook.test` event, sent to this webhook only; its delivery shows in the log."""

    @extend_schema(request=None, responses={202: TestSent})
    def post(self, request: Request, pk: int) -> Response:
        event = services.webhook_test(
            subscription=_mine(request, pk), by=request_user(request), ip=client_ip(request)
        )
        return Response({"event": event.position}, status=status.HTTP_202_ACCEPTED)


class WebhookDeliveryListApi(APIView):
    """The webhook's deliveries, the newest event first: state, tries, last answer, next try."""

    pagination_class = Pagination

    @extend_schema(responses=DeliveryOutput(many=True))
    def get(self, request: Request, pk: int) -> Response:
        return paginated_response(
            request=request,
            view=self,
            queryset=webhook_deliveries(subscription=_mine(request, pk)),
            serializer_class=DeliveryOutput,
        )
