"""The announced-sample marks on Redis: a page's bits are set a whole byte at a time where
they can be, with the same bitmap as setting each bit."""

from __future__ import annotations

import redis
from django.conf import settings
from hypothesis import given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st

from core.live import RedisBus, _whole_bytes, redis_channel

KEY = "test:live-marks"


@given(start=st.integers(0, 100), length=st.integers(0, 100))
def test_whole_bytes_and_the_rest_are_exactly_the_range(start, length):
    seqs = range(start, start + length)
    whole, ragged = _whole_bytes(seqs)
    assert sorted([*whole, *ragged]) == list(seqs)
    assert whole.start % 8 == 0
    assert len(whole) % 8 == 0


@hypothesis_settings(max_examples=60, deadline=None)
@given(pages=st.lists(st.tuples(st.integers(1, 200), st.integers(0, 60)), max_size=4))
def test_the_bitmap_is_the_one_setting_each_bit_would_give(pages):
    client = redis.Redis.from_url(settings.REDIS_URL)
    client.delete(KEY, KEY + ":each")
    bus = RedisBus(settings.REDIS_URL, redis_channel(""))
    for start, length in pages:
        seqs = range(start, start + length)
        bus.publish_marked("test-marks", "{}", KEY, seqs)
        for seq in seqs:
            client.setbit(KEY + ":each", seq, 1)
    assert (bus.marks(KEY) or b"").rstrip(b"\0") == (bus.marks(KEY + ":each") or b"").rstrip(b"\0")
    client.delete(KEY, KEY + ":each")
