"""The Redis task transport keeps a worker alive through a Redis outage."""

from __future__ import annotations

import uuid

import pytest
from django.conf import settings
from kombu import Connection, Exchange, Queue

from portal.celery import app as celery_app
from portal.redis_broker import Transport


def test_the_workers_use_the_fixed_transport_on_redis():
    assert settings.CELERY_BROKER_URL.startswith("redis://"), "make test runs on Redis"
    with celery_app.connection_for_write() as connection:
        assert connection.transport_cls == "portal.redis_broker:Transport"
        assert isinstance(connection.transport, Transport)


def test_closing_a_channel_after_its_transport_lost_the_connection_is_a_connection_error():
    """The order kombu closes in while Celery reconnects: the transport first, then a channel
    holding an unacknowledged message. kombu's own channel raises ``AttributeError`` there, and
    Celery stops the worker; this one raises an error Celery reconnects after."""
    queue_name = f"test-{uuid.uuid4().hex}"
    queue = Queue(queue_name, Exchange(queue_name), routing_key=queue_name)
    connection = Connection(settings.CELERY_BROKER_URL, transport=Transport)
    channel = connection.default_channel
    try:
        producer = connection.Producer(channel)
        producer.publish({"n": 1}, exchange=queue.exchange, routing_key=queue_name, declare=[queue])
        message = channel.basic_get(queue_name, no_ack=False)
        assert message is not None, "the message was published"
        assert channel.qos._delivered, "the message is held unacknowledged"
        channel._disconnect_pools()
        connection.transport.client = None

        with pytest.raises(connection.connection_errors):
            channel.close()
    finally:
        cleanup = Connection(settings.CELERY_BROKER_URL, transport=Transport)
        with cleanup:
            cleanup.default_channel.queue_delete(queue_name)
