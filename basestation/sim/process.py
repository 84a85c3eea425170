"""``python -m basestation.sim``: the simulated robot as its own process, in real time.

The robot's radio listens on a loopback UDP port; the base station's emulated RFM69 (the
agent's side, ``make_simulated_spi`` with ``transport="udp"``) sends to it. Killing the agent
leaves the robot running, and it stops by itself on its dead-man, as the real one does.

Once a second one log line goes to stdout. A loopback TCP inspection port answers the line
``state`` with the robot's state as one JSON line (velocity, track_m, e_stop_latched,
dead_man, ...), for tests and for looking at the simulation from outside.
"""

from __future__ import annotations

import argparse
import json
import signal
import socketserver
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from types import FrameType
from typing import Any

from basestation.sim.channel import LOOPBACK, UdpChannel
from basestation.sim.config import SimConfig, SimConfigError
from basestation.sim.firmware import FirmwareError
from basestation.sim.robot import RobotState, SimulatedRobot
from basestation.sim.spi import DEFAULT_BASE_PORT, DEFAULT_INSPECT_PORT, DEFAULT_ROBOT_PORT

LOOP_SLEEP_S = 0.001


class InspectionServer(socketserver.ThreadingTCPServer):
    """Loopback TCP: a client sends ``state\\n`` and gets one JSON line back."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, port: int, snapshot: Callable[[], dict[str, Any]]) -> None:
        self.snapshot = snapshot
        super().__init__((LOOPBACK, port), _InspectionHandler)

    @property
    def port(self) -> int:
        return int(self.server_address[1])


class _InspectionHandler(socketserver.StreamRequestHandler):
    timeout = 2.0
    server: InspectionServer

    def handle(self) -> None:
        try:
            request = self.rfile.readline(64).decode("ascii", "replace").strip()
        except (OSError, TimeoutError):
            return
        if request == "state":
            answer: dict[str, Any] = self.server.snapshot()
        else:
            answer = {"error": f"unknown request {request[:32]!r}; send 'state'"}
        self.wfile.write(json.dumps(answer).encode() + b"\n")


def format_state(state: RobotState) -> str:
    flags = "|".join(state.status_flags) or "-"
    return (
        f"t={state.robot_clock_ms / 1000:9.1f}s track={state.track_m:8.3f}m side={state.side} "
        f"v={state.velocity_mps:+.3f}m/s applied={state.applied_velocity_mps:+.3f}m/s "
        f"duty={state.duty:3d} dir={state.direction} battery={state.battery_v:.2f}V "
        f"fix={state.gps_fix} status={flags} rx={state.frames_received} "
        f"tx={state.frames_answered}"
    )


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m basestation.sim",
        description="Run the simulated AMazING robot (firmware core + rail physics) in real "
        "time, its radio on a loopback UDP port.",
    )
    parser.add_argument(
        "--radio-port",
        type=int,
        default=DEFAULT_ROBOT_PORT,
        help=f"UDP port of the robot's radio (default {DEFAULT_ROBOT_PORT}; 0: any free port)",
    )
    parser.add_argument(
        "--peer-port",
        type=int,
        default=DEFAULT_BASE_PORT,
        help=f"UDP port of the base station's radio (default {DEFAULT_BASE_PORT})",
    )
    parser.add_argument(
        "--inspect-port",
        type=int,
        default=DEFAULT_INSPECT_PORT,
        help=f"TCP inspection port (default {DEFAULT_INSPECT_PORT}; 0: any free port)",
    )
    parser.add_argument("--config", help="simulator configuration file (.toml or .json)")
    parser.add_argument("--latency-ms", type=float, default=0.0, help="extra air latency")
    parser.add_argument(
        "--loss", type=float, default=0.0, help="probability that a frame is corrupted (0..1)"
    )
    parser.add_argument("--seed", type=int, default=None, help="overrides the config's seed")
    parser.add_argument("--log-interval-s", type=float, default=1.0)
    parser.add_argument(
        "--duration-s", type=float, default=None, help="exit after this long (default: run on)"
    )
    return parser


class _StopFlag:
    """Set by SIGTERM or SIGINT; the robot's loop reads it between steps."""

    requested = False


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    for name in ("radio_port", "peer_port", "inspect_port"):
        port = getattr(args, name)
        if not 0 <= port < 65536 or (name == "peer_port" and port == 0):
            print(f"error: --{name.replace('_', '-')} {port} is not a usable port", file=sys.stderr)
            return 2
    try:
        config = SimConfig.load(args.config) if args.config else SimConfig()
        if args.seed is not None:
            config = replace(config, seed=args.seed)
        channel = UdpChannel(
            local_port=args.radio_port,
            peer_port=args.peer_port,
            latency_s=args.latency_ms / 1000.0,
            loss_probability=args.loss,
            seed=config.seed,
        )
    except (SimConfigError, ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    try:
        robot = SimulatedRobot(config, channel=channel, start_s=time.monotonic())
    except FirmwareError as error:
        channel.close()
        print(f"error: {error}", file=sys.stderr)
        return 2

    lock = threading.Lock()
    snapshot: dict[str, Any] = robot.state().to_json()

    def current() -> dict[str, Any]:
        with lock:
            return dict(snapshot)

    try:
        inspector = InspectionServer(args.inspect_port, current)
    except OSError as error:
        channel.close()
        print(f"error: inspection port {args.inspect_port}: {error}", file=sys.stderr)
        return 2
    threading.Thread(target=inspector.serve_forever, name="sim-inspect", daemon=True).start()

    # A plain flag, not a threading.Event: a second signal can arrive while the handler of the
    # first is inside Event.set, whose lock is not reentrant, and the process would hang there.
    stop = _StopFlag()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.requested = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    print(
        f"amazing-sim: robot ready radio=udp://{LOOPBACK}:{channel.local_port} "
        f"peer=udp://{LOOPBACK}:{args.peer_port} inspect=tcp://{LOOPBACK}:{inspector.port}",
        flush=True,
    )
    started = time.monotonic()
    next_log = started + args.log_interval_s
    try:
        while not stop.requested:
            now = time.monotonic()
            robot.advance_to(now)
            state = robot.state()
            with lock:
                snapshot = state.to_json()
            if now >= next_log:
                print(format_state(state), flush=True)
                next_log += args.log_interval_s * max(
                    1, int((now - next_log) // args.log_interval_s) + 1
                )
            if args.duration_s is not None and now - started >= args.duration_s:
                break
            time.sleep(LOOP_SLEEP_S)
    finally:
        inspector.shutdown()
        inspector.server_close()
        channel.close()
        robot.close()
    print("amazing-sim: robot stopped", flush=True)
    return 0
