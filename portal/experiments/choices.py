from django.db import models


class Direction(models.TextChoices):
    CW = "cw", "clockwise"
    CCW = "ccw", "counter-clockwise"


class RunState(models.TextChoices):
    SCHEDULED = "scheduled", "scheduled"
    STAGED = "staged", "staged on the base station"
    RUNNING = "running", "running"
    COLLECTING = "collecting", "collecting data"
    COMPLETED = "completed", "completed"
    CANCELLED = "cancelled", "cancelled"
    FAILED = "failed", "failed"
    INTERRUPTED = "interrupted", "interrupted (partial data kept)"


RUN_ACTIVE_STATES = (RunState.STAGED, RunState.RUNNING, RunState.COLLECTING)
RUN_END_STATES = (
    RunState.COMPLETED,
    RunState.CANCELLED,
    RunState.FAILED,
    RunState.INTERRUPTED,
)
