"""A tiny RFM69 driver for the tests, written from docs/protocol.md §1 only (the way the
robot's firmware driver is), so the emulated chip is exercised through SPI exactly as a real
driver would use it. It is not the agent's driver (basestation/radio/)."""

from __future__ import annotations

from collections.abc import Callable

from basestation.sim.rfm69 import SpiDevice

REG_FIFO = 0x00
REG_OPMODE = 0x01
REG_VERSION = 0x10
REG_RSSIVALUE = 0x24
REG_DIOMAPPING1 = 0x25
REG_IRQFLAGS1 = 0x27
REG_IRQFLAGS2 = 0x28
REG_AESKEY1 = 0x3E
REG_PACKETCONFIG2 = 0x3D

MODE_STANDBY = 0x04
MODE_TX = 0x0C
MODE_RX = 0x10

MODE_READY = 0x80
PACKET_SENT = 0x08
PAYLOAD_READY = 0x04


def protocol_registers(node: int, network: int, *, aes: bool) -> list[tuple[int, int]]:
    """docs/protocol.md §1, register by register."""
    return [
        (REG_OPMODE, MODE_STANDBY),
        (0x02, 0x00),
        (0x03, 0x02),
        (0x04, 0x40),
        (0x05, 0x03),
        (0x06, 0x33),
        (0x07, 0x6C),
        (0x08, 0x40),
        (0x09, 0x00),
        (0x11, 0x7F),
        (0x18, 0x88),
        (0x19, 0x42),
        (REG_DIOMAPPING1, 0x40),
        (0x26, 0x07),
        (REG_IRQFLAGS2, 0x10),
        (0x29, 0xDC),
        (0x2C, 0x00),
        (0x2D, 0x03),
        (0x2E, 0x88),
        (0x2F, 0x2D),
        (0x30, network),
        (0x37, 0x94),
        (0x38, 0x42),
        (0x39, node),
        (0x3A, 0xFF),
        (0x3C, 0x8F),
        (REG_PACKETCONFIG2, 0x13 if aes else 0x12),
        (0x6F, 0x30),
    ]


class TinyDriver:
    def __init__(
        self,
        spi: SpiDevice,
        *,
        clock: Callable[[], float],
        sleep: Callable[[float], None],
        node: int = 1,
        network: int = 100,
        aes_key: bytes | None = None,
    ) -> None:
        self.spi = spi
        self.clock = clock
        self.sleep = sleep
        self.node = node
        self.network = network
        self.aes_key = aes_key

    def read(self, address: int) -> int:
        return self.spi.xfer2([address & 0x7F, 0])[1]

    def write(self, address: int, value: int) -> None:
        self.spi.xfer2([address | 0x80, value])

    def _wait(self, address: int, mask: int, timeout_s: float, poll_s: float) -> bool:
        deadline = self.clock() + timeout_s
        while not self.read(address) & mask:
            if self.clock() > deadline:
                return False
            self.sleep(poll_s)
        return True

    def set_mode(self, mode: int) -> bool:
        self.write(REG_OPMODE, mode)
        return self._wait(REG_IRQFLAGS1, MODE_READY, 0.010, 20e-6)

    def begin(self) -> None:
        assert self.read(REG_VERSION) == 0x24, "no radio"
        for address, value in protocol_registers(self.node, self.network, aes=bool(self.aes_key)):
            self.write(address, value)
        if self.aes_key:
            self.spi.xfer2([REG_AESKEY1 | 0x80, *self.aes_key])
        assert self.set_mode(MODE_STANDBY)
        self.start_rx()

    def start_rx(self) -> None:
        self.write(REG_DIOMAPPING1, 0x40)
        self.set_mode(MODE_RX)

    def send(self, frame: bytes) -> bool:
        self.set_mode(MODE_STANDBY)
        self.write(REG_IRQFLAGS2, 0x10)
        self.spi.xfer2([REG_FIFO | 0x80, *frame])
        self.write(REG_DIOMAPPING1, 0x00)
        self.write(REG_OPMODE, MODE_TX)
        sent = self._wait(REG_IRQFLAGS2, PACKET_SENT, 0.030, 100e-6)
        self.set_mode(MODE_STANDBY)
        self.start_rx()
        return sent

    def receive(self, timeout_s: float) -> tuple[bytes, int] | None:
        if not self._wait(REG_IRQFLAGS2, PAYLOAD_READY, timeout_s, 250e-6):
            return None
        rssi_dbm = -self.read(REG_RSSIVALUE) // 2
        self.set_mode(MODE_STANDBY)
        length = self.spi.xfer2([REG_FIFO, 0])[1]
        body = self.spi.xfer2([REG_FIFO] + [0] * length)[1:]
        self.start_rx()
        return bytes([length, *body]), rssi_dbm

    def exchange(self, frame: bytes, timeout_s: float = 0.030) -> tuple[bytes, int] | None:
        if not self.send(frame):
            return None
        return self.receive(timeout_s)
