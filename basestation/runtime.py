"""The live parts of one agent (store, robot, manager, control loop), owned by its Flask app."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from flask import Flask, current_app

from basestation.config import AgentConfig
from basestation.control import ControlLoop, ControlStats
from basestation.housekeeping import Housekeeper
from basestation.manager import RunManager
from basestation.robot import Robot
from basestation.robots import build_robot
from basestation.store import RunStore
from basestation.system import DiskSpace, disk_space

logger = logging.getLogger(__name__)

EXTENSION_KEY = "basestation"

try:
    AGENT_VERSION = version("amazing-mobile-node")
except PackageNotFoundError:  # running from a source tree that was never installed
    AGENT_VERSION = "0+unknown"


@dataclass
class AgentRuntime:
    config: AgentConfig
    store: RunStore
    robot: Robot
    manager: RunManager
    control_loop: ControlLoop | None = None
    housekeeper: Housekeeper | None = None
    # Replaceable so that tests can play a full disk.
    disk_probe: Callable[[Path], DiskSpace | None] = field(default=disk_space)
    closed: bool = False

    @classmethod
    def open(cls, config: AgentConfig, *, robot: Robot | None = None) -> AgentRuntime:
        store = RunStore(config.store_path)
        # A run still marked running was cut off by a crash or kill of the previous agent:
        # its samples are kept, its state says why it stopped.
        store.mark_interrupted(now_s=time.time(), reason="agent restarted during run")
        if robot is None:
            robot = build_robot(config)
        manager = RunManager(store=store, robot=robot, config=config)
        return cls(config=config, store=store, robot=robot, manager=manager)

    def start_control_loop(self) -> None:
        """Start the control loop, the store writer and the store's housekeeping (threads)."""
        self.manager.writer.start()
        self.control_loop = ControlLoop(
            self.manager.tick,
            hz=self.config.control_hz,
            rt_priority=self.config.rt_priority,
            urgent=self.manager.urgent,
            urgent_at=self.manager.next_start_s,
        )
        self.manager.on_wake = self.control_loop.wake
        self.control_loop.start()
        self.housekeeper = Housekeeper(self.store, retention_s=self.config.retention_s)
        self.housekeeper.start()

    def disk(self) -> DiskSpace | None:
        return self.disk_probe(self.config.data_dir)

    def control_stats(self) -> ControlStats:
        if self.control_loop is not None:
            return self.control_loop.stats()
        # Driven by hand (tests): the manager still counts its ticks.
        return ControlStats(
            hz=self.config.control_hz,
            running=False,
            ticks=self.manager.snapshot.ticks,
            late_ticks=0,
            skipped_ticks=0,
            tick_errors=0,
            max_lateness_s=0.0,
        )

    def close(self) -> None:
        """Stop the loop, command the robot to zero, close the store. Idempotent."""
        if self.closed:
            return
        self.closed = True
        if self.control_loop is not None:
            self.control_loop.stop()
        if self.housekeeper is not None:
            self.housekeeper.stop()
        try:
            self.manager.shutdown(time.time())
        finally:
            self.manager.writer.stop()
            self.store.close()
            close_robot = getattr(self.robot, "close", None)
            if close_robot is not None:
                close_robot()


def get_runtime(app: Flask | None = None) -> AgentRuntime:
    runtime = (app or current_app).extensions[EXTENSION_KEY]
    assert isinstance(runtime, AgentRuntime)
    return runtime
