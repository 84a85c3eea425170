from __future__ import annotations

from django.conf import settings
from django.db import models


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

    @property
    def velocities_mps(self) -> list[float]:
        return [float(s["velocity_mps"]) for s in self.segments]
