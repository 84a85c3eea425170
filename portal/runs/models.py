from __future__ import annotations

from typing import Any

from django.conf import settings
from django.db import models
from django.db.models import Value

from basestation.contract import SAMPLE_FIELDS
from core.cache import ChangeTrackedQuerySet, Generation, track_changes
from portal.experiments.choices import Direction
from portal.experiments.models import Experiment
from portal.runs.states import Cause, RunState


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
    # What the final check against the agent found missing (``collection.MissingRange``):
    # gaps in the sequence numbers, and the part of the program never recorded.
    # (A database default too: rows written by the previous release during an upgrade.)
    missing = models.JSONField(default=list, blank=True, db_default=Value([], models.JSONField()))
    # How the run was made: the agent, its robot's firmware, the clock, the link, the portal,
    # recorded at staging and at collection (``portal/runs/provenance.py``).
    provenance = models.JSONField(
        default=dict, blank=True, db_default=Value({}, models.JSONField())
    )
    # The run this one repeats ("Run again"): same program, same limits.
    repeat_of = models.ForeignKey(
        "self", null=True, blank=True, on_delete=models.SET_NULL, related_name="repeats"
    )
    # Limits asked for at booking ({"max_velocity_mps", "max_accel_mps2"}; a repeat takes the
    # ones its original was staged with). Staging sends them within the robot's current
    # limits; None: the robot's.
    limits = models.JSONField(null=True, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    objects = ChangeTrackedQuerySet["Run"].as_manager()

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

    # What booking checks of the program (``bookings.rules.Program``): the run's own copy.
    @property
    def duration_s(self) -> float:
        return float(sum(float(s["duration_s"]) for s in self.segments))

    @property
    def velocities_mps(self) -> list[float]:
        return [float(s["velocity_mps"]) for s in self.segments]


class RunEvent(models.Model):
    """Every state change of a run, with when and why (append-only)."""

    run = models.ForeignKey(Run, on_delete=models.CASCADE, related_name="events")
    from_state = models.CharField(max_length=16, choices=RunState.choices, blank=True)
    to_state = models.CharField(max_length=16, choices=RunState.choices)
    at = models.DateTimeField(auto_now_add=True)
    reason = models.TextField(blank=True)
    cause = models.CharField(max_length=16, choices=Cause.choices, blank=True)
    # The person behind a booking or admin cause; none for the workers.
    by = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="+",
    )

    objects = ChangeTrackedQuerySet["RunEvent"].as_manager()

    class Meta:
        ordering = ["at", "pk"]

    def __str__(self) -> str:
        return f"{self.from_state or '∅'} → {self.to_state}"


class DryRun(models.Model):
    """A program tried on a simulated robot of its own before a booking is spent on it
    (``portal/runs/services/dry_run.py``). It has no booking and no robot: nothing in it names
    a resource or a base station, and its samples are kept here, whole, as the model made
    them."""

    class State(models.TextChoices):
        QUEUED = "queued", "waiting for a simulator"
        RUNNING = "running", "running on the simulator"
        COMPLETED = "completed", "completed"
        FAILED = "failed", "failed"

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="dry_runs"
    )
    # The experiment it was tried from; the program is copied, as a run's is.
    experiment = models.ForeignKey(
        Experiment, null=True, blank=True, on_delete=models.SET_NULL, related_name="dry_runs"
    )
    title = models.CharField(max_length=200)
    segments = models.JSONField()
    # The limits it ran under: the strictest of the robots the owner may book.
    limits = models.JSONField()
    rail_length_m = models.FloatField()
    state = models.CharField(
        max_length=16, choices=State.choices, default=State.QUEUED, db_index=True
    )
    # Which of the simulator places it holds while running (0 … DRY_RUN_SLOTS-1): a unique
    # place per running dry run is what bounds how many run at once.
    slot = models.PositiveSmallIntegerField(null=True, blank=True)
    reason = models.TextField(blank=True)
    # The agent's samples (its API's JSON objects), once it has run.
    samples = models.JSONField(default=list, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    started_at = models.DateTimeField(null=True, blank=True)
    ended_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ["-created_at", "-pk"]
        constraints = [
            models.UniqueConstraint(
                fields=["slot"],
                condition=models.Q(state="running"),
                name="dry_run_one_per_slot",
            ),
            models.CheckConstraint(
                condition=models.Q(state="running", slot__isnull=False)
                | (~models.Q(state="running") & models.Q(slot__isnull=True)),
                name="dry_run_slot_while_running",
            ),
        ]

    def __str__(self) -> str:
        return f"dry run {self.pk} ({self.state})"

    @property
    def duration_s(self) -> float:
        return float(sum(float(s["duration_s"]) for s in self.segments))


# The columns of a sample are the contract's (``basestation/contract.py``): the order the
# downloads give them in. A test checks the model below against the contract.
__all__ = [
    "SAMPLE_FIELDS",
    "DryRun",
    "MeasurementPoint",
    "MeasurementSeries",
    "Run",
    "RunEvent",
    "Sample",
]


class Sample(models.Model):
    """One telemetry sample of a run, as recorded by the base station at its control tick.

    Its columns are the contract's ``SAMPLE_COLUMNS``, by name (a test compares them).
    """

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


class MeasurementSeries(models.Model):
    """A researcher's own measurement on a run (a signal strength, a throughput): named
    value columns over time, on the researcher's clock plus ``clock_offset_s``.

    ``summary`` is the series placed on the run's path (``portal/runs/measurements.py``):
    how many points fell where, per metre of track and per grid cell statistics, and a
    downsampled line per column; made again whenever points or the offset change, so that
    the run page reads one row, not a million.
    """

    run = models.ForeignKey(Run, on_delete=models.CASCADE, related_name="measurements")
    name = models.SlugField(max_length=64)
    unit = models.CharField(max_length=32, blank=True)
    description = models.TextField(blank=True, max_length=2000)
    # The node that measured (for example the fixed node the robot's node talked to).
    source_node = models.CharField(max_length=64, blank=True)
    # The value columns, in order: ``MeasurementPoint.column_index`` indexes this list.
    columns = models.JSONField()
    # Added to every point's time to put it on the base station's clock.
    clock_offset_s = models.FloatField(default=0.0)
    # When the measuring machine marked the robot's first segment beginning (on its own
    # clock): the offset that aligns the two is offered (``summary["suggested_offset_s"]``).
    marker_at = models.DateTimeField(null=True, blank=True)
    point_count = models.PositiveIntegerField(default=0)
    summary = models.JSONField(default=dict, blank=True)
    created_by = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.SET_NULL, null=True, related_name="+"
    )
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ["run", "name"]
        constraints = [
            models.UniqueConstraint(fields=["run", "name"], name="measurement_run_name_unique"),
        ]

    def __str__(self) -> str:
        return f"{self.run_id}/{self.name}"


class MeasurementPoint(models.Model):
    """One value of one column of a series at one time (the researcher's clock, UTC).

    The key is (series, column, time): a point sent twice is stored once, and the table
    carries no other index to keep up while a million rows are copied in.
    """

    pk = models.CompositePrimaryKey("series", "column_index", "t")
    # No index of its own: the key begins with it.
    series = models.ForeignKey(
        MeasurementSeries, on_delete=models.CASCADE, related_name="+", db_index=False
    )
    column_index = models.PositiveSmallIntegerField()
    t = models.DateTimeField()
    # NULL: the file had no value there.
    value = models.FloatField(null=True)

    def __str__(self) -> str:
        return f"{self.series_id}[{self.column_index}]@{self.t.isoformat()}"


# What the runs lists show (state, events, samples stored): cached until a run or its events
# change. Samples arrive by COPY, which no signal sees: their ingest moves it on itself.
RUNS = Generation("runs")
track_changes(RUNS, Run, RunEvent)


class SelfCheck(models.Model):
    """A run of the robot's standard self-check (``portal.runs.self_check``) and its verdict:
    the figures its samples gave, judged against the limits and the robot's baseline."""

    class State(models.TextChoices):
        PENDING = "pending", "waiting for its run"
        PASSED = "passed", "passed"
        FAILED = "failed", "out of tolerance"
        NOT_RUN = "not_run", "did not run to its end"

    run = models.OneToOneField(Run, on_delete=models.CASCADE, related_name="self_check")
    resource = models.ForeignKey(
        "bookings.Resource", on_delete=models.CASCADE, related_name="self_checks"
    )
    # The program's parameters the figures are read with (``self_check.Program``).
    check_velocity_mps = models.FloatField()
    accel_mps2 = models.FloatField()
    lap_m = models.FloatField()
    state = models.CharField(max_length=8, choices=State.choices, default=State.PENDING)
    figures = models.JSONField(default=dict, blank=True)
    # Each figure out of tolerance, as a line an admin can act on.
    problems = models.JSONField(default=list, blank=True)
    # The baseline the figures were judged against (none: the limits alone).
    baseline = models.JSONField(null=True, blank=True)
    reason = models.TextField(blank=True)  # why it did not run, or was not measured
    evaluated_at = models.DateTimeField(null=True, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ["-created_at"]
        indexes = [models.Index(fields=["resource", "-created_at"], name="selfcheck_resource")]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(check_velocity_mps__gt=0)
                & models.Q(accel_mps2__gt=0)
                & models.Q(lap_m__gt=0),
                name="selfcheck_program_positive",
            ),
        ]

    def __str__(self) -> str:
        return f"self-check {self.pk} of {self.resource_id} ({self.state})"


class SelfCheckBaseline(models.Model):
    """What a robot's self-checks are judged against: its first passing check's figures, or
    those of a check an admin chose."""

    resource = models.OneToOneField(
        "bookings.Resource", on_delete=models.CASCADE, related_name="self_check_baseline"
    )
    figures = models.JSONField()
    source = models.ForeignKey(SelfCheck, on_delete=models.SET_NULL, null=True, blank=True)
    set_by = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.SET_NULL, null=True, blank=True
    )
    set_at = models.DateTimeField(auto_now=True)

    def __str__(self) -> str:
        return f"self-check baseline of {self.resource_id}"


class SelfCheckSchedule(models.Model):
    """A robot's self-check booked every day at ``at``, the testbed's wall-clock time (or in
    the first free slot after it), for the admin who set it while they stay staff."""

    resource = models.OneToOneField(
        "bookings.Resource", on_delete=models.CASCADE, related_name="self_check_schedule"
    )
    at = models.TimeField()
    set_by = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE)
    # The last day's time it booked a check for (or found it could not): booked once a day.
    booked_for = models.DateTimeField(null=True, blank=True)
    set_at = models.DateTimeField(auto_now=True)

    def __str__(self) -> str:
        return f"self-check of {self.resource_id} daily at {self.at}"
