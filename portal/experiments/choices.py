from django.db import models


class Direction(models.TextChoices):
    """The contract's directions (``basestation.contract.DIRECTIONS``; a test compares them)."""

    CW = "cw", "clockwise"
    CCW = "ccw", "counter-clockwise"
