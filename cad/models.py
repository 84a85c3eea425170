"""The models ``python -m cad`` knows, by name."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import cadquery as cq

from cad import antenna_branch, bs_case, gps_mount, robot_case


class Built(Protocol):
    def parts(self) -> dict[str, cq.Solid]: ...

    def exploded(self) -> cq.Shape: ...


@dataclass(frozen=True)
class Model:
    name: str
    summary: str
    build: Callable[[], Built]


MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        Model("bs_case", "base-station case: Pi 4, communication board, fan duct", bs_case.build),
        Model("gps_mount", "base-station GPS antenna support with tilting cradle", gps_mount.build),
        Model("robot_case", "robot control-board case, gasketed, frame tabs", robot_case.build),
        Model("antenna_branch", "robot antenna branch: 2 SMA + tilting GPS", antenna_branch.build),
    )
}
