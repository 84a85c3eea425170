"""How long a packet is on air, from the RFM69 datasheet's packet format (section 5.5).

One formula for both ends of the simulated air and for the driver: the simulator delivers a
frame when it has been on air this long, and the driver does not look for what cannot have
happened yet (a frame sent, or a reply received, before its bytes could cross the air).
"""

from __future__ import annotations

import math
from typing import Final

#: The RFM69's crystal: bit rate and carrier registers are in units of it.
FXOSC_HZ: Final = 32_000_000
#: docs/protocol.md §1: 55 555 bit/s (RegBitrate 0x0240).
DEFAULT_BITRATE_RAW: Final = 0x0240
#: AES-128 encrypts the packet's secret part in blocks of this many bytes.
AES_BLOCK: Final = 16


def airtime_s(
    frame_len: int,
    *,
    bitrate_bps: float = FXOSC_HZ / DEFAULT_BITRATE_RAW,
    preamble_bytes: int = 3,
    sync_bytes: int = 2,
    crc: bool = True,
    aes: bool = False,
    plaintext_bytes: int = 2,
) -> float:
    """Seconds on air for a packet of ``frame_len`` FIFO bytes (docs/protocol.md §5).

    Preamble + sync word + packet + CRC at the bit rate. With AES the bytes after the
    ``plaintext_bytes`` (length and address byte in variable-length mode with address
    filtering) are encrypted in 16-byte blocks, so they are padded to a multiple of 16.
    """
    if frame_len < 0:
        raise ValueError(f"frame_len {frame_len} < 0")
    packet = frame_len
    if aes:
        clear = min(plaintext_bytes, frame_len)
        secret = frame_len - clear
        packet = clear + math.ceil(secret / AES_BLOCK) * AES_BLOCK
    on_air_bytes = preamble_bytes + sync_bytes + packet + (2 if crc else 0)
    return on_air_bytes * 8 / bitrate_bps
