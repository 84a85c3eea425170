"""The soak's report: markdown, the plot of runs over time with the faults marked, and its
section of docs/reliability.md."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from bench import sections
from bench.soak.model import (
    CHECKS,
    FAULT_NAMES,
    REPORT,
    ROBOTS,
    SoakResult,
)

# -- the report ----------------------------------------------------------------------------


def _clock(seconds: float) -> str:
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


def report_markdown(result: SoakResult, *, plot_name: str | None) -> str:
    states = Counter(r.state for r in result.runs)
    kinds = Counter(f.kind for f in result.faults)
    booked = [b for b in result.bookings if b.reservation_id is not None]
    retried = [b for b in booked if b.attempts > 1]
    refused = [b for b in result.bookings if b.reservation_id is None]
    with_nodes = [r for r in result.runs if r.nodes]
    lost = sum(max(0, r.agent_samples - r.samples) for r in result.runs)
    lines = [
        f"### {result.minutes:g} minutes, seed {result.seed}",
        "",
        f"Started {result.started_at[:16].replace('T', ' ')} UTC on {result.machine}.",
        "",
        "| runs | completed | interrupted | failed | cancelled | with a fixed node |",
        "| --- | --- | --- | --- | --- | --- |",
        f"| {len(result.runs)} | {states['completed']} | {states['interrupted']} "
        f"| {states['failed']} | {states['cancelled']} | {len(with_nodes)} |",
        "",
        "| samples on the agents | stored | lost | duplicated | leases | orphan leases "
        "| bookings without their lease |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        f"| {result.samples_on_agents:,} | {result.samples_stored:,} | {lost} "
        f"| {len(result.misses['no_duplicates'])} | {result.leases} | {result.orphan_leases} "
        f"| {result.bookings_without_lease} |".replace(",", " "),
        "",
        f"Bookings: {len(booked)} made, {len(retried)} of them after retries with their key "
        f"({sum(b.attempts - 1 for b in retried)} retries), {len(refused)} refused"
        + (" (" + "; ".join(sorted({b.refused[:100] for b in refused})) + ")" if refused else "")
        + f". Processes started again after a death: {len(result.restarts)}.",
        "",
        f"Faults injected: {len(result.faults)}.",
        "",
        "| fault | count | at (min:s since the start) |",
        "| --- | --- | --- |",
    ]
    for kind, name in FAULT_NAMES.items():
        times = [f for f in result.faults if f.kind == kind]
        at = ", ".join(
            _clock(f.at_s) + (f" ({f.target})" if f.kind == "agent" else "") for f in times
        )
        lines.append(f"| {name} | {kinds[kind]} | {at or '–'} |")
    lines += ["", "| check | result |", "| --- | --- |"]
    for key, words in CHECKS.items():
        misses = result.misses[key]
        shown = "; ".join(misses[:5]) + (" …" if len(misses) > 5 else "")
        lines.append(f"| {words} | {'ok' if not misses else f'{len(misses)} missed: {shown}'} |")
    if result.awaiting_redelivery:
        lines += [
            "",
            "Tasks a killed worker had taken, which Redis hands out again after its "
            "visibility timeout (their work was redone by the sweeps meanwhile): "
            + "; ".join(result.awaiting_redelivery)
            + ".",
        ]
    interrupted = [r for r in result.runs if r.state in ("interrupted", "failed")]
    if interrupted:
        lines += ["", "Runs not completed:", ""]
        lines += [f"- run {r.id} on {r.robot}, {r.state}: {r.reason}" for r in interrupted]
    if result.holds:
        lines += ["", "Robot holds:", ""]
        for hold in result.holds:
            cause = hold["explained_by"]
            why = (
                f"after the {FAULT_NAMES[cause['kind']]} ({cause['target']}) killed at "
                f"{_clock(cause['at_s'])}; put back in service"
                if cause
                else "unexplained"
            )
            lines.append(f"- {hold['robot']} at {_clock(hold['at_s'])}: {hold['reason']} — {why}")
    if plot_name:
        lines += ["", f"![Runs over time, faults marked]({plot_name})"]
    return "\n".join(lines)


STATE_COLOURS = {
    "completed": "#2e7d32",
    "interrupted": "#ef6c00",
    "failed": "#c62828",
    "cancelled": "#757575",
}


def plot(result: SoakResult, path: Path) -> None:
    """Runs over time, one lane per robot (hatched: with a fixed node), coloured by how they
    ended; the faults as vertical lines, one colour per kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.artist import Artist
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    fig, ax = plt.subplots(figsize=(12, 3.6), dpi=100)
    lanes = {robot: i for i, robot in enumerate(ROBOTS)}
    for run in result.runs:
        ax.barh(
            lanes[run.robot],
            (run.end_s - run.start_s) / 60,
            left=run.start_s / 60,
            height=0.6,
            color=STATE_COLOURS.get(run.state, "#9e9e9e"),
            edgecolor="white",
            linewidth=0.5,
            hatch="//" if run.nodes else None,
        )
    palette = plt.get_cmap("tab10")
    kind_colour = {kind: palette(i) for i, kind in enumerate(FAULT_NAMES)}
    for fault in result.faults:
        ax.axvline(fault.at_s / 60, color=kind_colour[fault.kind], linewidth=1.6, alpha=0.9)
    ax.set_yticks(list(lanes.values()), list(lanes))
    ax.set_ylim(-0.7, len(lanes) - 0.3)
    ax.set_xlabel("minutes since the start")
    ax.set_title(
        f"Soak: {len(result.runs)} runs, {len(result.faults)} faults "
        f"({result.minutes:g} min, seed {result.seed})"
    )
    handles: list[Artist] = [Patch(color=c, label=s) for s, c in STATE_COLOURS.items()]
    handles.append(Patch(facecolor="white", edgecolor="black", hatch="//", label="fixed node"))
    kinds_seen = {f.kind for f in result.faults}
    handles += [
        Line2D([0], [0], color=kind_colour[k], label=FAULT_NAMES[k])
        for k in FAULT_NAMES
        if k in kinds_seen
    ]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_report(markdown: str) -> None:
    """Replace (or add) the soak's section of docs/reliability.md, between its markers."""
    sections.write_section(
        REPORT, begin="<!-- soak -->", end="<!-- /soak -->", body=markdown, title="# Reliability"
    )
