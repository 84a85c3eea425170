"""A synthetic signal strength for the simulated robot: what its node would hear from a fixed
node, pushed to the portal while a run goes on.

``python -m basestation.sim.rssi --portal URL --token TOKEN --run RUN`` follows the run's
samples through the portal's API (``GET /api/v1/runs/{id}/samples/?after=…``) and, for each
sample, sends the signal strength at the robot's place then to the run's series ``rssi``
(``POST /api/v1/runs/{id}/measurements/rssi/``), at the sample's own time, until the run has
ended and every sample has been answered. The model is the log-distance path loss with
log-normal shadowing:

    RSSI(d) = tx_dbm - loss_at_1m_db - 10 · exponent · log10(max(d, 1 m)) + X,   X ~ N(0, σ²)

with ``d`` the distance from the fixed node to the robot's place on the rail, and ``X`` drawn
from a generator seeded by ``--seed`` (the same run, the same values). Demos and tests use
it; it is a model, not a measurement.

``--watch`` instead of ``--run`` follows every run of the token's owner that is running, each
as it starts (``make run``'s demo: the experimenter's runs get their signal strength and the
run page its heatmap). ``--token-file`` reads the token from a file rather than the command
line, where other users of the machine could see it.
"""

from __future__ import annotations

import argparse
import math
import random
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import requests

from basestation.telemetry.rail import XY, Rail

RUN_END_STATES: Final = ("completed", "cancelled", "failed", "interrupted")
DEFAULT_NODE_AT: Final = (30.0, 0.0)


@dataclass(frozen=True)
class PathLoss:
    """The log-distance path loss model with shadowing (all in dB)."""

    tx_dbm: float = 0.0
    loss_at_1m_db: float = 40.0
    exponent: float = 2.7
    shadowing_db: float = 4.0

    def mean_dbm(self, distance_m: float) -> float:
        """The signal strength without shadowing at ``distance_m``."""
        return (
            self.tx_dbm
            - self.loss_at_1m_db
            - 10.0 * self.exponent * math.log10(max(distance_m, 1.0))
        )

    def sample_dbm(self, distance_m: float, rng: random.Random) -> float:
        """One reading: the mean plus a shadowing drawn from ``rng``."""
        return self.mean_dbm(distance_m) + rng.gauss(0.0, self.shadowing_db)


def distance_m(rail: Rail, node_at: XY, track_m: float) -> float:
    """From the fixed node (metres east and north of the rail's centre) to the robot's
    place at ``track_m`` along the rail."""
    x_m, y_m = rail.xy_at(track_m)
    return math.hypot(x_m - node_at[0], y_m - node_at[1])


def node_place(rail: Rail, name: str | None, at: XY | None) -> XY:
    """The fixed node's place: a node of the rail's file by name, or given in metres."""
    if name is None:
        return at if at is not None else DEFAULT_NODE_AT
    for node_name, (lat_deg, lon_deg) in rail.nodes:
        if node_name == name:
            return rail.frame.to_xy_m(lat_deg, lon_deg)
    known = ", ".join(node for node, _ in rail.nodes) or "none"
    raise SystemExit(f"rssi: no fixed node {name!r} on the rail (it has: {known})")


@dataclass
class Pusher:
    """Follows one run's samples and sends a reading for each."""

    portal: str
    token: str
    run: int
    rail: Rail
    node_at: XY
    model: PathLoss
    rng: random.Random
    series: str = "rssi"
    source_node: str = ""
    poll_s: float = 1.0
    timeout_s: float = 3600.0

    def __post_init__(self) -> None:
        self.session = requests.Session()
        self.session.headers["Authorization"] = f"Token {self.token}"
        self.base = f"{self.portal.rstrip('/')}/api/v1/runs/{self.run}"

    def readings(self, samples: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [
            {
                "t": sample["t"],
                self.series: round(
                    self.model.sample_dbm(
                        distance_m(self.rail, self.node_at, sample["track_m"]), self.rng
                    ),
                    2,
                ),
            }
            for sample in samples
        ]

    def _send(self, points: list[dict[str, Any]]) -> None:
        answer = self.session.post(
            f"{self.base}/measurements/{self.series}/",
            json={
                "points": points,
                "unit": "dBm",
                "source_node": self.source_node,
                "description": "synthetic: log-distance path loss with shadowing",
            },
            timeout=30,
        )
        if answer.status_code not in (200, 201):
            raise SystemExit(
                f"rssi: the portal refused a batch: {answer.status_code} {answer.text}"
            )

    def follow(self) -> int:
        """Until the run has ended and each sample has its reading; how many were sent."""
        after, sent = 0, 0
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            answer = self.session.get(
                f"{self.base}/samples/", params={"after": after, "limit": 5000}, timeout=30
            )
            answer.raise_for_status()
            page = answer.json()
            if page["samples"]:
                self._send(self.readings(page["samples"]))
                sent += len(page["samples"])
                after = page["last_seq"]
                continue
            if page["state"] in RUN_END_STATES:
                return sent
            time.sleep(self.poll_s)
        raise SystemExit(f"rssi: run {self.run} did not end within {self.timeout_s:g} s")


def watch(portal: str, token: str, pusher_for: Callable[[int], Pusher], poll_s: float) -> None:
    """Follow each run of the token's owner that is running, in a thread of its own, as it
    starts; forever (the process is stopped by a signal). A portal that does not answer is
    asked again at the next poll."""
    session = requests.Session()
    session.headers["Authorization"] = f"Token {token}"
    followed: set[int] = set()
    while True:
        try:
            answer = session.get(
                f"{portal.rstrip('/')}/api/v1/runs/", params={"state": "running"}, timeout=30
            )
            answer.raise_for_status()
            running = [run["id"] for run in answer.json()["results"]]
        except (requests.RequestException, ValueError, KeyError) as exc:
            print(f"rssi: could not list the running runs ({exc}); asking again", flush=True)
            running = []
        for run_id in running:
            if run_id not in followed:
                followed.add(run_id)
                print(f"rssi: following run {run_id}", flush=True)
                threading.Thread(
                    target=_follow_one, args=(pusher_for(run_id),), daemon=True
                ).start()
        time.sleep(poll_s)


def _follow_one(pusher: Pusher) -> None:
    try:
        sent = pusher.follow()
    except (requests.RequestException, SystemExit) as exc:
        print(f"rssi: run {pusher.run}: stopped following ({exc})", flush=True)
        return
    print(f"rssi: {sent} readings sent to run {pusher.run}'s series {pusher.series}", flush=True)


def _xy(text: str) -> XY:
    x_text, _, y_text = text.partition(",")
    try:
        return float(x_text), float(y_text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"give X,Y in metres, not {text!r}") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m basestation.sim.rssi", description=__doc__)
    parser.add_argument("--portal", required=True, help="the portal's address")
    token = parser.add_mutually_exclusive_group(required=True)
    token.add_argument("--token", help="an API token of the run's owner")
    token.add_argument("--token-file", type=Path, help="or the file that holds it")
    runs = parser.add_mutually_exclusive_group(required=True)
    runs.add_argument("--run", type=int, help="the run to follow")
    runs.add_argument(
        "--watch", action="store_true", help="or every run of the token's owner, as it runs"
    )
    parser.add_argument("--rail", help="the rail's file (default: the built-in rail)")
    parser.add_argument("--node", help="a fixed node of the rail's file, by name")
    parser.add_argument("--node-at", type=_xy, help="or its place: X,Y metres east, north")
    parser.add_argument("--series", default="rssi", help="the series's name (rssi)")
    parser.add_argument("--seed", type=int, default=1, help="the shadowing's seed (1)")
    parser.add_argument("--shadowing-db", type=float, default=PathLoss.shadowing_db)
    parser.add_argument("--exponent", type=float, default=PathLoss.exponent)
    parser.add_argument("--poll-s", type=float, default=1.0)
    args = parser.parse_args(argv)
    rail = Rail.configured(args.rail)
    node_at = node_place(rail, args.node, args.node_at)
    token = args.token or args.token_file.read_text().strip()

    def pusher_for(run_id: int) -> Pusher:
        return Pusher(
            portal=args.portal,
            token=token,
            run=run_id,
            rail=rail,
            node_at=node_at,
            model=PathLoss(exponent=args.exponent, shadowing_db=args.shadowing_db),
            # Watching many runs: each its own values, the same again for the same run.
            rng=random.Random(args.seed if args.run else args.seed * 1_000_003 + run_id),
            series=args.series,
            source_node=args.node or f"node at {node_at[0]:g},{node_at[1]:g} m",
            poll_s=args.poll_s,
        )

    if args.watch:
        watch(args.portal, token, pusher_for, max(args.poll_s, 1.0))
        return 0
    pusher = pusher_for(args.run)
    sent = pusher.follow()
    print(f"rssi: {sent} readings sent to run {args.run}'s series {args.series}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
