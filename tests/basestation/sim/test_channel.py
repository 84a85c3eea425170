"""The air: seeded loss, latency, cuts, and the UDP transport on 127.0.0.1."""

from __future__ import annotations

import socket
import time

from basestation.protocol import CommandFrame, Direction, encode_command
from basestation.sim.channel import InProcessChannel, UdpChannel, airtime_s
from basestation.sim.clock import FakeClock
from basestation.sim.config import RadioConfig
from basestation.sim.rfm69 import EmulatedRFM69
from basestation.sim.robot import FrameRadio
from tests.basestation.sim.driver import TinyDriver

FRAME = encode_command(CommandFrame(seq=1, velocity_mm_s=500, direction=Direction.CW))


def radios(channel: InProcessChannel) -> tuple[FrameRadio, list[tuple[float, bytes, float]]]:
    heard: list[tuple[float, bytes, float]] = []
    sender = FrameRadio(RadioConfig(node=1), lambda *_: None)
    receiver = FrameRadio(RadioConfig(node=2), lambda *args: heard.append(args))
    sender.connect(channel)
    receiver.connect(channel)
    return sender, heard


def delivered_pattern(seed: int, loss: float, count: int = 400) -> list[bool]:
    channel = InProcessChannel(clock=FakeClock(), loss_probability=loss, seed=seed)
    sender, heard = radios(channel)
    pattern = []
    for i in range(count):
        before = len(heard)
        sender.transmit(FRAME, start_s=i * 0.02)
        pattern.append(len(heard) > before)
    return pattern


def test_loss_is_seeded_and_close_to_its_probability() -> None:
    pattern = delivered_pattern(seed=5, loss=0.3)
    assert pattern == delivered_pattern(seed=5, loss=0.3)
    assert pattern != delivered_pattern(seed=6, loss=0.3)
    assert 0.63 < sum(pattern) / len(pattern) < 0.77


def test_latency_delays_the_arrival() -> None:
    channel = InProcessChannel(clock=FakeClock(), latency_s=0.004)
    sender, heard = radios(channel)
    sender.transmit(FRAME, start_s=1.0)
    assert heard[0][0] == 1.0 + 0.004 + airtime_s(len(FRAME))


def test_a_cut_link_carries_nothing_until_restored() -> None:
    channel = InProcessChannel(clock=FakeClock())
    sender, heard = radios(channel)
    channel.cut()
    sender.transmit(FRAME, start_s=0.0)
    assert heard == []
    channel.restore()
    sender.transmit(FRAME, start_s=0.1)
    assert len(heard) == 1
    assert channel.stats.cut_dropped == 1


def test_two_emulated_chips_talk_over_udp_on_loopback() -> None:
    with UdpChannel() as a, UdpChannel() as b:
        a.connect(b.local_port)
        b.connect(a.local_port)
        chips = [EmulatedRFM69(channel=a), EmulatedRFM69(channel=b)]
        drivers = [
            TinyDriver(chip, clock=time.monotonic, sleep=time.sleep, node=node)
            for chip, node in zip(chips, (1, 2), strict=True)
        ]
        for driver in drivers:
            driver.begin()
        assert drivers[0].send(FRAME)
        received = drivers[1].receive(1.0)
        assert received is not None
        assert received[0] == FRAME
        # A stray datagram is counted and ignored.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stray:
            stray.sendto(b"not a frame", ("127.0.0.1", b.local_port))
        deadline = time.monotonic() + 1.0
        while b.stats.malformed == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert b.stats.malformed == 1
        a.cut()
        assert drivers[0].send(FRAME)  # the chip transmits; the air drops it
        assert drivers[1].receive(0.1) is None
