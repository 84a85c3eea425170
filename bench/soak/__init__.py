"""``make soak``: the whole system for ``SOAK_MINUTES`` under random faults, then checked.

Everything runs as in production (``portal.processes``, through ``bench/stack.py``): a
private PostgreSQL cluster (``initdb`` in a scratch directory, on a free port, so that it can
be restarted without disturbing the machine's server), a private redis-server (broker, cache,
live bus), the stand-in testbed scheduler, two agents each with its simulated robot, both
Celery workers (runs and mail), beat, the web server, the streams server and the collector.

- **Driver**: for each robot a client books runs back to back through the public API (the
  ``amazing`` command's client), about one in three holding a fixed node too (a lease on the
  stand-in). Each booking has its own ``X-Idempotency-Key`` and is retried with it while the
  portal does not answer, answers 5xx, or is still handling the same key.
- **Chaos**: every 60 to 180 s (seeded), one of the runs worker, the mail worker, beat, Redis,
  an agent, the web server or the stand-in is killed with SIGKILL, and PostgreSQL is
  restarted once (an immediate shutdown: a crash, recovered at the start). Whatever died is
  started again as the launcher would (``portal.launcher``'s pauses).
- **Operator**: a robot the health check takes out of booking is put back in service (as an
  admin would, audited) when a fault injected on its agent explains the hold; any other hold
  stays, and fails the soak.
- **Checks** at the end, each a list of misses (:data:`CHECKS`): every run in an end state;
  each run holds exactly its agent's samples (sequence, time and values); each interrupted
  run's missing ranges equal the agent's gaps; no sample stored twice; no idempotency key
  booked twice; no lease on the stand-in without its booking, no booking without its lease;
  no task left in the broker; every hold lifted or explained.

``python -m bench.soak --minutes 30`` writes the report (markdown, JSON, and a plot of runs
over time with the faults marked) into ``--out``; ``--report`` also puts it into
docs/reliability.md. The exit code is 1 when a check found a miss.

The package: ``model`` (the faults, bookings, runs and result it records, the checks' names),
``system`` (the system, the drivers, the operator and the chaos), ``checks`` (what is checked
at the end), ``report`` (markdown, plot, docs/reliability.md); ``run`` and ``main`` here.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path

from bench.soak.model import (
    CHAOS_EVERY_S,
    CHECKS,
    DEFAULT_MINUTES,
    FAULT_NAMES,
    PLOT,
    PROGRAM_S,
    REPORT,
    SoakResult,
    say,
)
from bench.soak.report import plot, report_markdown, write_report
from bench.soak.system import Soak
from bench.stack import REPO

__all__ = ["CHECKS", "FAULT_NAMES", "Soak", "SoakResult", "main", "run"]


def run(
    *,
    minutes: float = DEFAULT_MINUTES,
    seed: int = 1,
    chaos_every_s: tuple[float, float] = CHAOS_EVERY_S,
    program_s: float = PROGRAM_S,
    work: Path | None = None,
    until_each_fault: bool = False,
) -> SoakResult:
    """One soak in ``work`` (a scratch directory by default, removed when it passes)."""
    scratch = work is None
    work = work or Path(tempfile.mkdtemp(prefix="soak-"))
    result = Soak(
        work=work,
        minutes=minutes,
        seed=seed,
        chaos_every_s=chaos_every_s,
        program_s=program_s,
        until_each_fault=until_each_fault,
    ).run()
    if scratch and result.ok:
        shutil.rmtree(work, ignore_errors=True)
    elif not result.ok:
        say(f"the processes' logs are in {work / 'logs'}")
    return result


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.soak", description=__doc__)
    parser.add_argument(
        "--minutes",
        type=float,
        default=float(os.environ.get("SOAK_MINUTES") or DEFAULT_MINUTES),
        help="how long runs are booked and faults injected (SOAK_MINUTES; default 30)",
    )
    parser.add_argument("--seed", type=int, default=int(os.environ.get("SOAK_SEED") or 1))
    parser.add_argument(
        "--chaos-every-s",
        nargs=2,
        type=float,
        default=list(CHAOS_EVERY_S),
        metavar=("MIN", "MAX"),
        help="pause between faults, drawn between these (default 60 180)",
    )
    parser.add_argument("--program-s", type=float, default=PROGRAM_S, help="each run's program")
    parser.add_argument(
        "--until-each-fault",
        action="store_true",
        help="stop booking one pause after every kind of fault has occurred once "
        "(at most --minutes)",
    )
    parser.add_argument("--out", type=Path, help="write soak.md, soak.json and soak.png here")
    parser.add_argument(
        "--report", action="store_true", help="also write the report into docs/reliability.md"
    )
    parser.add_argument("--work", type=Path, help="keep the servers' data and logs here")
    args = parser.parse_args(argv)
    low, high = args.chaos_every_s
    if not 0 < low <= high:
        parser.error("--chaos-every-s: 0 < MIN <= MAX")
    result = run(
        minutes=args.minutes,
        seed=args.seed,
        chaos_every_s=(low, high),
        program_s=args.program_s,
        work=args.work,
        until_each_fault=args.until_each_fault,
    )
    plots: list[tuple[Path, str]] = []
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "soak.json").write_text(json.dumps(result.to_json(), indent=1))
        plots.append((args.out / "soak.png", "soak.png"))
        plot(result, args.out / "soak.png")
        (args.out / "soak.md").write_text(report_markdown(result, plot_name="soak.png"))
    if args.report:
        plot(result, PLOT)
        write_report(report_markdown(result, plot_name=PLOT.name))
        say(f"written to {REPORT.relative_to(REPO)}")
    print(report_markdown(result, plot_name=None))
    return 0 if result.ok else 1
