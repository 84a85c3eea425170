"""What the booking services share: telling people of a change once it is committed."""

from __future__ import annotations

from functools import partial
from typing import Any

from django.db import transaction

from bookings.tasks import reservation_notify


def _notify(kind: str, reservation_id: int, **extra: Any) -> None:
    transaction.on_commit(partial(reservation_notify.delay, kind, reservation_id, **extra))
