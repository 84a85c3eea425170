"""Checks shared by the parameter dataclasses."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import fields
from typing import Any


def check_sizes(params: Any, may_be_zero: Iterable[str] = ()) -> None:
    """Every number whose name ends in ``_mm`` or ``_deg`` must be > 0 (>= 0 if listed).

    The message names the parameter, so whoever set it knows what to change.
    """
    zero_ok = set(may_be_zero)
    for f in fields(params):
        if not f.name.endswith(("_mm", "_deg")):
            continue
        value = getattr(params, f.name)
        if not isinstance(value, int | float) or value != value:  # NaN is never a size
            raise ValueError(f"{f.name} must be a number, got {value!r}")
        if f.name in zero_ok:
            if value < 0:
                raise ValueError(f"{f.name} must be >= 0, got {value}")
        elif value <= 0:
            raise ValueError(f"{f.name} must be > 0, got {value}")
