"""The live parts of one agent (store, robot, manager, control loop), owned by its Flask app."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from flask import Flask, current_app

from basestation.config import AgentConfig
from basestation.control import ControlStats
from basestation.housekeeping import Housekeeper
from basestation.loop_process import LoopProcess
from basestation.manager import RunControl, RunManager
from basestation.robot import Robot, RobotLimits
from basestation.robots import build_robot
from basestation.store import RunStore
from basestation.system import DiskSpace, disk_space

logger = logging.getLogger(__name__)

EXTENSION_KEY = "basestation"


@dataclass
class AgentRuntime:
    """The agent's parts. Two ways to run the loop:

    - :meth:`open_with_loop_process` (the agent as served): the control loop, the robot and
      the run manager live in their own process (:mod:`basestation.loop_process`); this
      process keeps the run store for the API and reaches the loop through ``loop``.
    - :meth:`open` (tests, tools): the run manager and the robot live here and nothing moves
      until someone calls ``manager.tick(now_s)``.
    """

    config: AgentConfig
    store: RunStore
    in_process_manager: RunManager | None = None
    loop: LoopProcess | None = None
    housekeeper: Housekeeper | None = None
    # Replaceable so that tests can play a full disk.
    disk_probe: Callable[[Path], DiskSpace | None] = field(default=disk_space)
    closed: bool = False

    @classmethod
    def open(
        cls, config: AgentConfig, *, robot: Robot | None = None, durable: bool = True
    ) -> AgentRuntime:
        """``durable=False``: a scratch store (see :class:`RunStore`), for a dry run."""
        store = RunStore(config.store_path, durable=durable)
        # A run still marked running was cut off by a crash or kill of the previous agent:
        # its samples are kept, its state says why it stopped.
        store.mark_interrupted(now_s=time.time(), reason="agent restarted during run")
        if robot is None:
            robot = build_robot(config)
        manager = RunManager(store=store, robot=robot, config=config)
        return cls(config=config, store=store, in_process_manager=manager)

    @classmethod
    def open_with_loop_process(cls, config: AgentConfig) -> AgentRuntime:
        """Start the control loop's process (it opens the robot; ConfigError when it refuses
        the configuration), then the store's housekeeping here."""
        loop = LoopProcess(config)
        loop.start()
        try:
            store = RunStore(config.store_path)
        except BaseException:
            loop.close()
            raise
        runtime = cls(config=config, store=store, loop=loop)
        runtime.housekeeper = Housekeeper(store, retention_s=config.retention_s)
        runtime.housekeeper.start()
        return runtime

    @property
    def manager(self) -> RunManager:
        """The run manager of an agent opened with :meth:`open`."""
        if self.in_process_manager is None:
            raise RuntimeError("the run manager lives in the control loop's process")
        return self.in_process_manager

    @property
    def robot(self) -> Robot:
        return self.manager.robot

    @property
    def control(self) -> RunControl:
        """The run manager as the API uses it, wherever it lives."""
        if self.loop is not None:
            return self.loop
        return self.manager

    @property
    def robot_limits(self) -> RobotLimits | None:
        """What the robot confirmed of the agent's limits at start-up (None: a robot without
        firmware, such as the simple model, or one that did not answer)."""
        if self.loop is not None:
            return self.loop.robot_limits
        limits = getattr(self.manager.robot, "limits", None)
        return limits if isinstance(limits, RobotLimits) else None

    def limits_json(self) -> dict[str, object]:
        """The agent's effective limits, as ``GET /status`` reports them to the portal."""
        confirmed = self.robot_limits
        hard_max = None if confirmed is None else confirmed.hard_max_velocity_mps
        velocity = self.config.max_velocity_mps
        return {
            # The start refuses a configured limit above the hard maximum: min() only guards.
            "max_velocity_mps": velocity if hard_max is None else min(velocity, hard_max),
            "max_accel_mps2": self.config.max_accel_mps2,
            "robot_hard_max_velocity_mps": hard_max,
            "robot_confirmed": confirmed is not None,
        }

    def provenance_facts(self) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
        """How runs are made here now (basestation/provenance.py): this agent's facts and what
        the robot's firmware said of itself, as the control loop holds them (None, None while
        a loop process is not ready yet)."""
        if self.loop is not None:
            return self.loop.agent_facts, self.loop.firmware_facts
        return self.manager.agent_facts, self.manager.firmware_facts

    def disk(self) -> DiskSpace | None:
        return self.disk_probe(self.config.data_dir)

    @property
    def loop_started(self) -> bool:
        return self.loop is not None

    def loop_healthy(self) -> bool:
        """False only when a loop was started and is not ticking (or its writer died)."""
        if self.loop is not None:
            return self.loop.running
        return self.manager.writer.alive

    def control_stats(self) -> ControlStats:
        if self.loop is not None:
            return self.loop.stats()
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
        """Stop the loop (robot to zero, current run interrupted), close the store.
        Idempotent."""
        if self.closed:
            return
        self.closed = True
        if self.housekeeper is not None:
            self.housekeeper.stop()
        if self.loop is not None:
            try:
                self.loop.close()
            finally:
                self.store.close()
            return
        manager = self.manager
        try:
            manager.shutdown(time.time())
        finally:
            manager.writer.stop()
            self.store.close()
            close_robot = getattr(manager.robot, "close", None)
            if close_robot is not None:
                close_robot()


def get_runtime(app: Flask | None = None) -> AgentRuntime:
    runtime = (app or current_app).extensions[EXTENSION_KEY]
    assert isinstance(runtime, AgentRuntime)
    return runtime
