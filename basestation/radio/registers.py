"""RFM69 (Semtech SX1231) register map, from the datasheet's register table (section 6).

The one map for the driver (``basestation.radio.rfm69``) and the emulated chip
(``basestation.sim.rfm69``): both read the same datasheet, so both take every address, field
and bit from here and define none of their own (``tests/basestation/radio/test_registers.py``
holds them to it).

How the names read:

- ``REG_*`` is a register's address.
- A single-bit flag is the bit's mask in its register (``IRQ2_PAYLOAD_READY = 0x04``): test it
  with ``value & FLAG``, set it with ``|``.
- A field of several bits has ``<REGISTER>_<FIELD>_SHIFT`` and ``..._MASK`` (the mask in
  register position), and its values are **field values**, not shifted: RegOpMode's mode
  field holds ``MODE_TX = 3``, which is ``0x0C`` in the register. :func:`opmode_mode` and
  :func:`opmode_with_mode` (and the DIO0 pair) convert, so no caller shifts by hand.
"""

from __future__ import annotations

from typing import Final

# --- SPI access (datasheet 5.2.1) -------------------------------------------------------------
# The first byte of a transaction is the address, bit 7 set for a write; the address
# auto-increments over a burst except for RegFifo, whose every byte is the next FIFO byte.
SPI_WRITE: Final = 0x80
SPI_ADDRESS_MASK: Final = 0x7F

# --- addresses --------------------------------------------------------------------------------
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
REG_AFCMSB: Final = 0x1F
REG_AFCLSB: Final = 0x20
REG_FEIMSB: Final = 0x21
REG_FEILSB: Final = 0x22
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
REG_AESKEY1: Final = 0x3E  # RegAesKey1..16, MSB first
REG_TEMP1: Final = 0x4E
REG_TEMP2: Final = 0x4F
REG_TESTPA1: Final = 0x5A
REG_TESTPA2: Final = 0x5C
REG_TESTDAGC: Final = 0x6F

ALL: Final = {name: value for name, value in globals().items() if name.startswith("REG_")}

# --- sizes and identity -----------------------------------------------------------------------
CHIP_VERSION: Final = 0x24  # RegVersion of the SX1231 revision on RFM69 modules
FIFO_SIZE: Final = 66  # bytes
AES_KEY_BYTES: Final = 16  # RegAesKey1..16

# --- RegOpMode --------------------------------------------------------------------------------
OPMODE_SEQUENCER_OFF: Final = 0x80
OPMODE_LISTEN_ON: Final = 0x40
OPMODE_LISTEN_ABORT: Final = 0x20
OPMODE_MODE_SHIFT: Final = 2
OPMODE_MODE_MASK: Final = 0x1C
OPMODE_UNUSED_MASK: Final = 0x03  # bits 1-0 read 0
# Mode field values (bits 4-2): 0x0C in the register is MODE_TX.
MODE_SLEEP: Final = 0
MODE_STANDBY: Final = 1
MODE_FS: Final = 2
MODE_TX: Final = 3
MODE_RX: Final = 4
MODE_NAMES: Final = {
    MODE_SLEEP: "sleep",
    MODE_STANDBY: "standby",
    MODE_FS: "fs",
    MODE_TX: "tx",
    MODE_RX: "rx",
}  # the others (5-7) are reserved


def opmode_mode(opmode: int) -> int:
    """The mode field value of a RegOpMode value (``0x10`` -> ``MODE_RX``)."""
    return (opmode & OPMODE_MODE_MASK) >> OPMODE_MODE_SHIFT


def opmode_with_mode(opmode: int, mode: int) -> int:
    """RegOpMode ``opmode`` with its mode field set to ``mode``, the other bits kept
    (``opmode_with_mode(0x00, MODE_TX) == 0x0C``)."""
    return (opmode & ~OPMODE_MODE_MASK & 0xFF) | ((mode << OPMODE_MODE_SHIFT) & OPMODE_MODE_MASK)


# --- RegOsc1 ----------------------------------------------------------------------------------
OSC1_RCCAL_START: Final = 0x80
OSC1_RCCAL_DONE: Final = 0x40

# --- RegPaLevel -------------------------------------------------------------------------------
PALEVEL_PA0_ON: Final = 0x80  # RFM69W: PA0 on the RFIO pin
PALEVEL_PA1_ON: Final = 0x40  # RFM69HW/HCW: PA1 and PA2 on PA_BOOST
PALEVEL_PA2_ON: Final = 0x20
PALEVEL_OUTPUT_POWER_MASK: Final = 0x1F

# --- RegRssiConfig ----------------------------------------------------------------------------
RSSICONFIG_START: Final = 0x01
RSSICONFIG_DONE: Final = 0x02

# --- RegDioMapping1 (packet mode) -------------------------------------------------------------
DIOMAPPING1_DIO0_SHIFT: Final = 6
DIOMAPPING1_DIO0_MASK: Final = 0xC0
# DIO0 field values: what the pin shows depends on the mode (datasheet table 21).
DIO0_RX_CRC_OK: Final = 0
DIO0_RX_PAYLOAD_READY: Final = 1
DIO0_RX_SYNC_ADDRESS: Final = 2
DIO0_RX_RSSI: Final = 3
DIO0_TX_PACKET_SENT: Final = 0
DIO0_TX_TX_READY: Final = 1
DIO0_TX_PLL_LOCK: Final = 3


def dio0_mapping(dio_mapping1: int) -> int:
    """The DIO0 field value of a RegDioMapping1 value."""
    return (dio_mapping1 & DIOMAPPING1_DIO0_MASK) >> DIOMAPPING1_DIO0_SHIFT


def dio_mapping1_with_dio0(dio_mapping1: int, mapping: int) -> int:
    """RegDioMapping1 ``dio_mapping1`` with DIO0 mapped to ``mapping``, DIO1-3 kept."""
    return (dio_mapping1 & ~DIOMAPPING1_DIO0_MASK & 0xFF) | (
        (mapping << DIOMAPPING1_DIO0_SHIFT) & DIOMAPPING1_DIO0_MASK
    )


# --- RegIrqFlags1 -----------------------------------------------------------------------------
IRQ1_MODE_READY: Final = 0x80
IRQ1_RX_READY: Final = 0x40
IRQ1_TX_READY: Final = 0x20
IRQ1_PLL_LOCK: Final = 0x10
IRQ1_RSSI: Final = 0x08  # write 1 to clear
IRQ1_TIMEOUT: Final = 0x04
IRQ1_AUTO_MODE: Final = 0x02
IRQ1_SYNC_ADDRESS_MATCH: Final = 0x01  # write 1 to clear

# --- RegIrqFlags2 -----------------------------------------------------------------------------
IRQ2_FIFO_FULL: Final = 0x80
IRQ2_FIFO_NOT_EMPTY: Final = 0x40
IRQ2_FIFO_LEVEL: Final = 0x20
IRQ2_FIFO_OVERRUN: Final = 0x10  # write 1 to clear the flag and the FIFO
IRQ2_PACKET_SENT: Final = 0x08
IRQ2_PAYLOAD_READY: Final = 0x04
IRQ2_CRC_OK: Final = 0x02
IRQ2_LOW_BAT: Final = 0x01

# --- RegSyncConfig ----------------------------------------------------------------------------
SYNCCONFIG_SYNC_ON: Final = 0x80
SYNCCONFIG_SIZE_SHIFT: Final = 3
SYNCCONFIG_SIZE_MASK: Final = 0x38  # field value = sync word bytes - 1
SYNCCONFIG_TOLERANCE_MASK: Final = 0x07

# --- RegPacketConfig1 -------------------------------------------------------------------------
PACKET1_VARIABLE_LENGTH: Final = 0x80  # PacketFormat: length byte first
PACKET1_DC_FREE_MASK: Final = 0x60
PACKET1_CRC_ON: Final = 0x10
PACKET1_CRC_AUTO_CLEAR_OFF: Final = 0x08
PACKET1_ADDRESS_FILTERING_SHIFT: Final = 1
PACKET1_ADDRESS_FILTERING_MASK: Final = 0x06
# AddressFiltering field values.
ADDRESS_FILTERING_NONE: Final = 0
ADDRESS_FILTERING_NODE: Final = 1
ADDRESS_FILTERING_NODE_OR_BROADCAST: Final = 2

# --- RegFifoThresh ----------------------------------------------------------------------------
FIFOTHRESH_TX_START_NOT_EMPTY: Final = 0x80  # TxStartCondition; clear: FifoLevel
FIFOTHRESH_LEVEL_MASK: Final = 0x7F

# --- RegPacketConfig2 -------------------------------------------------------------------------
PACKET2_INTER_PACKET_RX_DELAY_SHIFT: Final = 4  # delay = 2 ** field bits
PACKET2_INTER_PACKET_RX_DELAY_MASK: Final = 0xF0
PACKET2_RESTART_RX: Final = 0x04  # reads 0
PACKET2_AUTO_RX_RESTART: Final = 0x02
PACKET2_AES_ON: Final = 0x01

# --- RegTestPa1 / RegTestPa2 (RFM69HW +20 dBm) ------------------------------------------------
TESTPA1_NORMAL: Final = 0x55
TESTPA1_BOOST: Final = 0x5D
TESTPA2_NORMAL: Final = 0x70
TESTPA2_BOOST: Final = 0x7C

# --- RegTestDagc ------------------------------------------------------------------------------
TESTDAGC_NORMAL: Final = 0x00
TESTDAGC_IMPROVED_LOW_BETA_ON: Final = 0x20  # improved margin, for AfcLowBetaOn = 1
TESTDAGC_IMPROVED_LOW_BETA_OFF: Final = 0x30  # improved margin, for AfcLowBetaOn = 0

#: The "Reset" column of the register summary (values after power-on reset; Semtech's
#: recommended "Default" column differs, and a driver must write what it needs itself).
RESET_VALUES: Final[dict[int, int]] = {
    0x01: 0x04, 0x02: 0x00, 0x03: 0x1A, 0x04: 0x0B, 0x05: 0x00, 0x06: 0x52,
    0x07: 0xE4, 0x08: 0xC0, 0x09: 0x00, 0x0A: 0x41, 0x0B: 0x00, 0x0C: 0x02,
    0x0D: 0x92, 0x0E: 0xF5, 0x0F: 0x20, 0x10: CHIP_VERSION, 0x11: 0x9F, 0x12: 0x09,
    0x13: 0x1A, 0x14: 0x40, 0x15: 0xB0, 0x16: 0x7B, 0x17: 0x9B, 0x18: 0x08,
    0x19: 0x86, 0x1A: 0x8A, 0x1B: 0x40, 0x1C: 0x80, 0x1D: 0x06, 0x1E: 0x10,
    0x1F: 0x00, 0x20: 0x00, 0x21: 0x00, 0x22: 0x00, 0x23: 0x02, 0x24: 0xFF,
    0x25: 0x00, 0x26: 0x05, 0x27: 0x80, 0x28: 0x00, 0x29: 0xFF, 0x2A: 0x00,
    0x2B: 0x00, 0x2C: 0x00, 0x2D: 0x03, 0x2E: 0x98,
    **{address: 0x00 for address in range(0x2F, 0x37)},  # RegSyncValue1..8
    0x37: 0x10, 0x38: 0x40, 0x39: 0x00, 0x3A: 0x00, 0x3B: 0x00, 0x3C: 0x0F,
    0x3D: 0x02,
    **{address: 0x00 for address in range(0x3E, 0x4E)},  # RegAesKey1..16
    0x4E: 0x01, 0x4F: 0x00, 0x58: 0x1B, 0x59: 0x09, 0x5A: 0x55, 0x5C: 0x70,
    0x5F: 0x08, 0x6F: 0x00, 0x71: 0x00,
}  # fmt: skip
