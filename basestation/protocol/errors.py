"""The one exception a frame decoder or encoder raises."""

from __future__ import annotations

from typing import Final, Literal

FrameErrorKind = Literal[
    "too_short",
    "length_mismatch",
    "reserved_bits",
    "unknown_version",
    "unknown_type",
    "size_mismatch",
    "out_of_range",
    "bad_enum",
]

FRAME_ERROR_KINDS: Final[frozenset[str]] = frozenset(
    {
        "too_short",
        "length_mismatch",
        "reserved_bits",
        "unknown_version",
        "unknown_type",
        "size_mismatch",
        "out_of_range",
        "bad_enum",
    }
)


class FrameError(ValueError):
    """A frame (or frame fields) that version 1 of the wire protocol does not allow.

    ``kind`` is one of the error kinds of docs/protocol.md §3, the same names the C++
    firmware and the shared test vectors use.
    """

    def __init__(self, kind: FrameErrorKind, message: str) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind: FrameErrorKind = kind
        self.message = message
