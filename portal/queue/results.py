"""A campaign's results: its completed runs grouped by their parameters' values, each group's
segment statistics as the mean over its repeats and their spread, and every run's measured
velocity for the overlaid chart. From each run's report (``portal/runs/selectors.py``
``run_report``, cached while the run is unchanged), so the run page, the compare page and a
campaign's table say the same numbers.

A campaign's program has one segment (``portal/queue/sweep.py``): its statistics are the run's.
The spread is the sample standard deviation over the repeats (n - 1 in the denominator);
one repeat has none.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from typing import Any, Final

from portal.queue.campaigns import campaign_requests
from portal.queue.models import Campaign, QueueRequest
from portal.runs.analysis import SegmentStats
from portal.runs.models import Run
from portal.runs.selectors import run_report
from portal.runs.states import RunState

# (attribute of SegmentStats, what the table heads it with): the statistics compared.
METRICS: Final = (
    ("mean_mps", "measured velocity (m/s, cw +)"),
    ("std_mps", "velocity's own sd (m/s)"),
    ("mean_abs_error_mps", "mean |error| (m/s)"),
    ("distance_m", "distance (m)"),
    ("duration_s", "duration (s)"),
)
# Points of each run's velocity on the overlaid chart: 200 runs stay a few megabytes.
CHART_POINTS: Final = 300


@dataclass(frozen=True)
class Spread:
    """A statistic over a group's repeats."""

    mean: float
    sd: float | None  # None for one repeat
    n: int

    @classmethod
    def of(cls, values: list[float]) -> Spread:
        sd = statistics.stdev(values) if len(values) > 1 else None
        return cls(statistics.fmean(values), sd, len(values))


@dataclass(frozen=True)
class ResultGroup:
    """The completed runs with the same parameters' values."""

    velocity_mps: float
    direction: str
    duration_s: float
    runs: tuple[int, ...]  # run ids, in the campaign's order
    metrics: dict[str, Spread]

    @property
    def label(self) -> str:
        return f"{self.velocity_mps:g} m/s {self.direction}, {self.duration_s:g} s"

    @property
    def metric_list(self) -> list[tuple[str, Spread | None]]:
        """Every statistic of ``METRICS`` in order, None where no repeat had samples."""
        return [(name, self.metrics.get(name)) for name, _ in METRICS]


@dataclass(frozen=True)
class CampaignRun:
    """A completed run of the campaign with its parameters and its segment's statistics."""

    request: QueueRequest
    run: Run
    stats: SegmentStats | None  # None when the segment holds no sample


def _key(parameters: dict[str, Any]) -> tuple[float, str, float]:
    return (
        float(parameters["velocity_mps"]),
        str(parameters["direction"]),
        float(parameters["duration_s"]),
    )


def campaign_runs_completed(campaign: Campaign) -> list[CampaignRun]:
    """The campaign's runs that completed, in its order, each with its report's segment."""
    done = []
    for request in campaign_requests(campaign):
        run: Run | None = getattr(request.reservation, "run", None)
        if run is None or run.state != RunState.COMPLETED or not request.parameters:
            continue
        segments = run_report(run=run).analysis.segments
        stats = segments[0] if segments and segments[0].samples else None
        done.append(CampaignRun(request, run, stats))
    return done


def campaign_results(completed: list[CampaignRun]) -> list[ResultGroup]:
    """One group per combination of values, sorted by velocity, direction and duration."""
    grouped: dict[tuple[float, str, float], list[CampaignRun]] = {}
    for one in completed:
        assert one.request.parameters is not None
        grouped.setdefault(_key(one.request.parameters), []).append(one)
    groups = []
    for (velocity_mps, direction, duration_s), members in sorted(grouped.items()):
        measured = [m.stats for m in members if m.stats is not None]
        metrics = {
            name: Spread.of([float(getattr(s, name)) for s in measured])
            for name, _ in METRICS
            if measured
        }
        groups.append(
            ResultGroup(
                velocity_mps, direction, duration_s, tuple(m.run.pk for m in members), metrics
            )
        )
    return groups


def campaign_chart(completed: list[CampaignRun], groups: list[ResultGroup]) -> list[dict[str, Any]]:
    """Each completed run's measured velocity from its first sample, with the index of its
    group (the chart colours a group's repeats alike)."""
    group_of = {run: index for index, group in enumerate(groups) for run in group.runs}
    out = []
    for one in completed:
        velocity = run_report(run=one.run, max_points=CHART_POINTS).series.get(
            "measured_mps", {"t": [], "y": []}
        )
        parameters = one.request.parameters or {}
        out.append(
            {
                "run": one.run.pk,
                "group": group_of[one.run.pk],
                "label": (
                    f"run {one.run.pk}: {groups[group_of[one.run.pk]].label}, "
                    f"repeat {parameters.get('repeat', 1)}"
                ),
                "velocity": {"t": velocity["t"], "y": velocity["y"]},
            }
        )
    return out


def spread_json(spread: Spread) -> dict[str, Any]:
    return {
        "mean": round(spread.mean, 4),
        "sd": None if spread.sd is None else round(spread.sd, 4),
        "n": spread.n,
    }


def campaign_results_json(groups: list[ResultGroup]) -> list[dict[str, Any]]:
    """The results as the API, the CLI and the campaign's package give them."""
    return [
        {
            "velocity_mps": group.velocity_mps,
            "direction": group.direction,
            "duration_s": group.duration_s,
            "runs": list(group.runs),
            "metrics": {name: spread_json(spread) for name, spread in group.metrics.items()},
        }
        for group in groups
    ]
