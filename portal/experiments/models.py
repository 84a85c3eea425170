from __future__ import annotations

from typing import Any

from django.conf import settings
from django.db import models

from portal.experiments.choices import Direction, RunState


class Experiment(models.Model):
    """A program for the mobile node: an ordered list of segments.

    ``segments`` is a list of ``{"velocity_mps": float, "direction": "cw"|"ccw",
    "duration_s": float}``; services validate it (the database only stores it).
    """

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="experiments"
    )
    title = models.CharField(max_length=200)
    segments = models.JSONField()
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ["-created_at"]

    def __str__(self) -> str:
        return self.title

    @property
    def duration_s(self) -> float:
        return float(sum(float(s["duration_s"]) for s in self.segments))


class Run(models.Model):
    """One execution of an experiment in a reservation on a mobile node.

    The program is copied from the experiment when the run is created, so editing the
    experiment later never changes what was (or will be) sent to the robot.
    """

    reservation = models.OneToOneField(
        "bookings.Reservation", on_delete=models.CASCADE, related_name="run"
    )
    # The mobile node of the reservation that drives this run.
    resource = models.ForeignKey("bookings.Resource", on_delete=models.PROTECT, related_name="runs")
    experiment = models.ForeignKey(Experiment, on_delete=models.PROTECT, related_name="runs")
    title = models.CharField(max_length=200)
    segments = models.JSONField()
    start_at = models.DateTimeField(db_index=True)
    end_at = models.DateTimeField()
    state = models.CharField(
        max_length=16, choices=RunState.choices, default=RunState.SCHEDULED, db_index=True
    )
    reason = models.TextField(blank=True)
    # Highest sample sequence number stored here; collection resumes after it.
    last_seq = models.PositiveIntegerField(default=0)
    agent_sample_count = models.PositiveIntegerField(null=True, blank=True)
    # Where the samples' track_m wraps, as the agent reported it: laps and passes need it.
    rail_length_m = models.FloatField(null=True, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ["-start_at"]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(end_at__gt=models.F("start_at")), name="run_end_after_start"
            ),
            models.CheckConstraint(
                condition=models.Q(rail_length_m__isnull=True) | models.Q(rail_length_m__gt=0),
                name="run_rail_length_positive",
            ),
        ]

    def __str__(self) -> str:
        return f"run {self.pk} ({self.state})"

    @property
    def agent_run_id(self) -> str:
        """The id under which this run is staged on its base-station agent."""
        return f"run-{self.pk}"

    @property
    def owner(self) -> Any:
        return self.reservation.owner


class RunEvent(models.Model):
    """Every state change of a run, with when and why (append-only)."""

    run = models.ForeignKey(Run, on_delete=models.CASCADE, related_name="events")
    from_state = models.CharField(max_length=16, choices=RunState.choices, blank=True)
    to_state = models.CharField(max_length=16, choices=RunState.choices)
    at = models.DateTimeField(auto_now_add=True)
    reason = models.TextField(blank=True)

    class Meta:
        ordering = ["at", "pk"]

    def __str__(self) -> str:
        return f"{self.from_state or '∅'} → {self.to_state}"


# The columns of a sample, in the order the agent sends, the worker stores and the downloads
# give them.
SAMPLE_FIELDS = (
    "seq",
    "t",
    "segment",
    "commanded_velocity_mps",
    "velocity_mps",
    "direction",
    "battery_v",
    "track_m",
    "fix_quality",
    "lat_deg",
    "lon_deg",
    "grid_id",
    "lap",
)


class Sample(models.Model):
    """One telemetry sample of a run, as recorded by the base station at its control tick."""

    run = models.ForeignKey(Run, on_delete=models.CASCADE, related_name="samples")
    seq = models.PositiveIntegerField()
    t = models.DateTimeField()
    segment = models.SmallIntegerField(null=True)
    commanded_velocity_mps = models.FloatField()
    velocity_mps = models.FloatField()
    direction = models.CharField(max_length=3, choices=Direction.choices)
    battery_v = models.FloatField()
    track_m = models.FloatField()
    # Where the robot was, when its GPS knew: fix 4 = RTK fixed, 5 = RTK float.
    fix_quality = models.SmallIntegerField(null=True)
    lat_deg = models.FloatField(null=True)
    lon_deg = models.FloatField(null=True)
    grid_id = models.CharField(max_length=8, null=True)
    lap = models.IntegerField(null=True)

    class Meta:
        ordering = ["run", "seq"]
        constraints = [
            # Collection may be retried or overlap; the pair (run, seq) is stored once.
            models.UniqueConstraint(fields=["run", "seq"], name="sample_run_seq_unique"),
        ]

    def __str__(self) -> str:
        return f"{self.run_id}#{self.seq}"
