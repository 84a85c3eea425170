from __future__ import annotations

from collections.abc import Sequence

from django.db.models import QuerySet

from bookings.models import Resource
from bookings.rules import Fit, robots_fitting
from bookings.selectors import mobiles_bookable
from core.accounts.models import User
from portal.experiments.models import Experiment


def experiments_visible(*, user: User) -> QuerySet[Experiment]:
    qs = Experiment.objects.select_related("owner")
    return qs if user.is_testbed_admin else qs.filter(owner=user)


def experiment_fits(experiment: Experiment, robots: Sequence[Resource] | None = None) -> list[Fit]:
    """For each robot the author may book, whether the program fits it (by name)."""
    robots = mobiles_bookable() if robots is None else robots
    return robots_fitting(robots, experiment.velocities_mps)


def fits_summary(fits: Sequence[Fit]) -> str:
    """Which robots a program fits, for a page: "Fits mobile-1; not mobile-2 (1.2 m/s, …)"."""
    good = [fit.limit.resource for fit in fits if fit.fits]
    bad = [f"{fit.limit.resource} ({fit.limit.describe()})" for fit in fits if not fit.fits]
    parts = []
    if good:
        parts.append(f"Fits {', '.join(good)}")
    if bad:
        parts.append(f"{'not' if good else 'Fits none of'} {', '.join(bad)}")
    return "; ".join(parts) + "." if parts else ""
