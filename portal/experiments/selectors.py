from __future__ import annotations

from django.db.models import QuerySet

from portal.accounts.models import User
from portal.experiments.models import Experiment


def experiments_visible(*, user: User) -> QuerySet[Experiment]:
    qs = Experiment.objects.select_related("owner")
    return qs if user.is_testbed_admin else qs.filter(owner=user)
