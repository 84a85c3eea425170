"""RFM69 (SX1231) register addresses, from the datasheet's register table.

One map for the driver (``basestation.radio.rfm69``) and the emulated chip
(``basestation.sim.rfm69``): both read the same datasheet, so they share its addresses.
"""

from __future__ import annotations

from typing import Final

REG_FIFO: Final = 0x00
REG_OPMODE: Final = 0x01
REG_DATAMODUL: Final = 0x02
REG_BITRATEMSB: Final = 0x03
REG_BITRATELSB: Final = 0x04
REG_FDEVMSB: Final = 0x05
REG_FDEVLSB: Final = 0x06
REG_FRFMSB: Final = 0x07
REG_FRFMID: Final = 0x08
REG_FRFLSB: Final = 0x09
REG_OSC1: Final = 0x0A
REG_VERSION: Final = 0x10
REG_PALEVEL: Final = 0x11
REG_LNA: Final = 0x18
REG_RXBW: Final = 0x19
REG_AFCFEI: Final = 0x1E
REG_RSSICONFIG: Final = 0x23
REG_RSSIVALUE: Final = 0x24
REG_DIOMAPPING1: Final = 0x25
REG_DIOMAPPING2: Final = 0x26
REG_IRQFLAGS1: Final = 0x27
REG_IRQFLAGS2: Final = 0x28
REG_RSSITHRESH: Final = 0x29
REG_PREAMBLEMSB: Final = 0x2C
REG_PREAMBLELSB: Final = 0x2D
REG_SYNCCONFIG: Final = 0x2E
REG_SYNCVALUE1: Final = 0x2F
REG_SYNCVALUE2: Final = 0x30
REG_PACKETCONFIG1: Final = 0x37
REG_PAYLOADLENGTH: Final = 0x38
REG_NODEADRS: Final = 0x39
REG_BROADCASTADRS: Final = 0x3A
REG_FIFOTHRESH: Final = 0x3C
REG_PACKETCONFIG2: Final = 0x3D
REG_AESKEY1: Final = 0x3E
REG_TEMP1: Final = 0x4E
REG_TEMP2: Final = 0x4F
REG_TESTPA1: Final = 0x5A
REG_TESTPA2: Final = 0x5C
REG_TESTDAGC: Final = 0x6F

ALL: Final = {name: value for name, value in globals().items() if name.startswith("REG_")}
