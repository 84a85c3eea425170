"""The announced-sample marks on Redis: marking a sample is claiming its announcement, so
pages published in any order, overlapping or repeated, announce each sample once, and each
event's last time is its last sample's."""

from __future__ import annotations

import json
import time

import redis
from django.conf import settings
from hypothesis import given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st

from core.live import RedisBus, redis_channel

KEY = "test:live-marks"
CHANNEL = "test-marks"


def _time_s(seq: int) -> float:
    return 1_764_000_000 + seq / 20 + 0.000_123


@hypothesis_settings(max_examples=60, deadline=None)
@given(pages=st.lists(st.tuples(st.integers(1, 200), st.integers(0, 60)), max_size=5))
def test_each_sample_of_overlapping_pages_is_announced_once(pages):
    client = redis.Redis.from_url(settings.REDIS_URL)
    client.delete(KEY)
    bus = RedisBus(settings.REDIS_URL, redis_channel(""))
    pubsub = client.pubsub(ignore_subscribe_messages=True)
    pubsub.subscribe(redis_channel(CHANNEL))
    try:
        for start, length in pages:
            bus.publish_samples(
                CHANNEL, KEY, start, [_time_s(s) for s in range(start, start + length)]
            )
        client.publish(redis_channel(CHANNEL), "end")  # everything before it has been heard
        events = []
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            message = pubsub.get_message(timeout=0.5)
            if message is None:
                continue
            if message["data"] == b"end":
                break
            events.append(json.loads(message["data"]))
        else:
            raise AssertionError("the end marker was never heard")
    finally:
        pubsub.close()

    announced = [seq for e in events for seq in range(e["first_seq"], e["last_seq"] + 1)]
    expected = {seq for start, length in pages for seq in range(start, start + length)}
    assert sorted(announced) == sorted(expected)  # each once
    for event in events:
        assert event["type"] == "samples"
        assert event["count"] == event["last_seq"] - event["first_seq"] + 1
        assert event["last_t"] == _time_s(event["last_seq"])
    marks = bus.marks(KEY) or b""
    assert {
        seq for seq in range(len(marks) * 8) if marks[seq // 8] >> (7 - seq % 8) & 1
    } == expected
    client.delete(KEY)
