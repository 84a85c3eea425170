"""A campaign's runs completed with samples of their own: each repeat a little off the
command in its own way, so that repeats differ and a results table has a spread."""

from __future__ import annotations

from portal.runs.models import Run
from portal.runs.services.collection import samples_ingest
from portal.runs.states import RunState

HZ = 20


def complete_with_samples(run: Run, repeat: int) -> None:
    """Samples of the run's one segment, each repeat a little off the command in its own way
    (so that the repeats differ and the spread is not zero), stored as collection does."""
    segment = run.segments[0]
    speed_mps = float(segment["velocity_mps"])
    count = round(float(segment["duration_s"]) * HZ)
    t0_s = run.start_at.timestamp()
    samples_ingest(
        run=run,
        samples=[
            {
                "seq": seq,
                "t": t0_s + (seq - 1) / HZ,
                "segment": 0,
                "commanded_velocity_mps": speed_mps,
                "velocity_mps": speed_mps * (1 + 0.03 * repeat) + 0.01 * (seq % 3),
                "direction": segment["direction"],
                "battery_v": 60.0,
                "track_m": (seq * speed_mps / HZ) % 100.0,
                "fix_quality": 4,
                "lat_deg": None,
                "lon_deg": None,
                "grid_id": None,
                "lap": None,
            }
            for seq in range(1, count + 1)
        ],
    )
    Run.objects.filter(pk=run.pk).update(state=RunState.COMPLETED, rail_length_m=100.0)
