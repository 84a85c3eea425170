"""The testbed's tunables: the timings, limits and sizes that are the product's own.

Django's settings (database, security, mail, static files) stay in ``portal/settings.py``;
these are the numbers an operator tunes for the testbed, each declared once here with its
type, default, lower bound and meaning. ``portal/settings.py`` reads each from the
environment of the same name (``TUNABLES`` below, in the README's order), and the code reads
them as any setting (``settings.RUN_STAGE_LEAD_S``), so a test can still override one.

The README's "Timings and limits" table is generated from this list
(``python -m portal.conf``) and ``tests/portal/test_settings.py`` holds it to it.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final, Generic, TypeVar

from django.core.exceptions import ImproperlyConfigured

Number = TypeVar("Number", int, float)

DAY_S: Final = 24 * 3600


@dataclass(frozen=True)
class Tunable(Generic[Number]):
    """One tunable: read from the environment variable ``name``, else ``default``.

    ``positive``: 0 is refused (an interval or a count of places); otherwise 0 is allowed and
    ``meaning`` says what it does. ``shown``: the default as the README writes it, when the
    bare number needs a gloss (``86400 (24 h)``).
    """

    name: str
    default: Number
    meaning: str
    positive: bool = True
    shown: str = ""

    def read(self, environ: Mapping[str, str] = os.environ) -> Number:
        raw = environ.get(self.name, "").strip()
        if not raw:
            return self.default
        kind = type(self.default)
        try:
            value = kind(raw)
        except ValueError:
            what = "a whole number" if kind is int else "a number"
            raise ImproperlyConfigured(f"{self.name}={raw!r}: give {what}") from None
        if value < 0 or (self.positive and value == 0) or value != value:
            bound = "greater than 0" if self.positive else "0 or more"
            raise ImproperlyConfigured(f"{self.name}={raw!r}: give a number {bound}")
        return value

    def readme_row(self) -> str:
        default = self.shown or f"`{self.default:g}`"
        return f"| `{self.name}` | {default} | {self.meaning} |"


# In the README's order: the run's timeline, the scheduler, dry runs, health, then the
# limits on what one person may ask for.
RUN_SWEEP_INTERVAL_S: Final = Tunable(
    "RUN_SWEEP_INTERVAL_S", 2.0, "how often beat looks for runs to stage and collect"
)
COLLECTOR_SCAN_INTERVAL_S: Final = Tunable(
    "COLLECTOR_SCAN_INTERVAL_S", 0.5, "how often the collector looks for runs to follow"
)
COLLECTOR_WAIT_S: Final = Tunable(
    "COLLECTOR_WAIT_S", 10, "longest wait of one of the collector's long-polls on an agent"
)
RUN_STAGE_LEAD_S: Final = Tunable(
    "RUN_STAGE_LEAD_S", 300.0, "how long before its start a run is staged on its agent"
)
RUN_REPEAT_LEAD_S: Final = Tunable(
    "RUN_REPEAT_LEAD_S",
    60.0,
    '"Run again" books the first free slot starting no sooner than this from now',
    positive=False,
)
RUN_START_GRACE_S: Final = Tunable(
    "RUN_START_GRACE_S",
    60.0,
    "a run its agent has not accepted this long after its start fails (its owner is "
    "e-mailed); a late stage starts the program late",
)
RUN_COLLECT_GRACE_S: Final = Tunable(
    "RUN_COLLECT_GRACE_S",
    600.0,
    "how long after a run's end its agent may stay out of reach (or keep samples back) "
    "before the run is closed with what was collected: `interrupted`, or `failed` with nothing",
)
RESERVATION_REMINDER_LEAD_S: Final = Tunable(
    "RESERVATION_REMINDER_LEAD_S",
    3600.0,
    "how long before its start a reservation's owner is reminded by e-mail",
)
SCHEDULER_SYNC_INTERVAL_S: Final = Tunable(
    "SCHEDULER_SYNC_INTERVAL_S",
    30.0,
    "how often the scheduler's leases are mirrored, orphan leases cancelled and bookings flagged",
)
SCHEDULER_ORPHAN_GRACE_S: Final = Tunable(
    "SCHEDULER_ORPHAN_GRACE_S",
    120.0,
    "SQLite only: how old a lease without its booking must be before it is cancelled",
    positive=False,
)
DRY_RUN_SLOTS: Final = Tunable(
    "DRY_RUN_SLOTS",
    2,
    "dry runs (*Try on the simulator*) run at once, each in a short-lived process of its "
    "own; the rest wait in line",
)
DRY_RUN_MAX_WAITING: Final = Tunable(
    "DRY_RUN_MAX_WAITING", 3, "dry runs one person may have waiting or running"
)
DRY_RUN_STALE_S: Final = Tunable(
    "DRY_RUN_STALE_S",
    300.0,
    "a dry run still marked running this long lost its worker: it fails and its place goes "
    "to the next",
)
DRY_RUN_KEEP_S: Final = Tunable(
    "DRY_RUN_KEEP_S",
    30.0 * DAY_S,
    "a finished dry run and its samples are deleted this long after it ended (hourly)",
    shown="`2592000` (30 days)",
)
SELF_CHECK_LEAD_S: Final = Tunable(
    "SELF_CHECK_LEAD_S",
    60.0,
    "a robot's self-check started without a time is booked in the first free slot starting "
    "no sooner than this from now",
)
SELF_CHECK_LAP_M: Final = Tunable(
    "SELF_CHECK_LAP_M",
    0.0,
    "how far the self-check's lap drives (`0`: once round the rail, as last measured)",
    positive=False,
)
HEALTH_POLL_INTERVAL_S: Final = Tunable(
    "HEALTH_POLL_INTERVAL_S",
    2.0,
    "how often each robot's agent status is read (and pushed to its console)",
)
HEALTH_UNREACHABLE_S: Final = Tunable(
    "HEALTH_UNREACHABLE_S", 120.0, "an agent out of reach this long takes its robot out of booking"
)
HEALTH_LOW_BATTERY_V: Final = Tunable(
    "HEALTH_LOW_BATTERY_V",
    50.0,
    "a filtered battery voltage under this takes the robot out of booking (`0`: only the "
    "agent's own low-battery flag)",
    positive=False,
)
RESERVATION_MAX_S: Final = Tunable("RESERVATION_MAX_S", 4 * 3600.0, "longest reservation")
STAFF_API_TOKEN_DAYS: Final = Tunable(
    "STAFF_API_TOKEN_DAYS",
    30,
    "a staff account's API token (made only from a session that passed its second factor) "
    "expires after at most this many days, and by default after exactly this many",
)
DOWNLOADS_IN_FLIGHT_MAX: Final = Tunable(
    "DOWNLOADS_IN_FLIGHT_MAX",
    3,
    "a run's downloads (CSV, JSON, zip) one user (or client address) may have in flight; "
    "the next answers 429 with `Retry-After`",
)
DOWNLOAD_SLOT_S: Final = Tunable(
    "DOWNLOAD_SLOT_S",
    900,
    "a download slot a killed process never gave back frees itself after this long",
)
IDEMPOTENCY_KEY_TTL_S: Final = Tunable(
    "IDEMPOTENCY_KEY_TTL_S",
    1.0 * DAY_S,
    "how long the answer to a POST sent with `X-Idempotency-Key` is replayed; older keys "
    "are deleted hourly and count as new",
    shown="`86400` (24 h)",
)
WEBHOOK_RETRY_FIRST_S: Final = Tunable(
    "WEBHOOK_RETRY_FIRST_S", 5.0, "a webhook's delivery that failed is tried again after this"
)
WEBHOOK_RETRY_MAX_S: Final = Tunable(
    "WEBHOOK_RETRY_MAX_S",
    6 * 3600.0,
    "the wait between a delivery's tries doubles up to this",
    shown="`21600` (6 h)",
)
WEBHOOK_RETRY_FOR_S: Final = Tunable(
    "WEBHOOK_RETRY_FOR_S",
    2 * DAY_S,
    "a delivery is tried for this long; then the webhook is paused and its owner told",
    shown="`172800` (48 h)",
)
WEBHOOKS_PER_USER_MAX: Final = Tunable("WEBHOOKS_PER_USER_MAX", 10, "webhooks one person may have")
MEASUREMENT_MAX_UPLOAD_BYTES: Final = Tunable(
    "MEASUREMENT_MAX_UPLOAD_BYTES",
    64 * 1024 * 1024,
    "the largest measurement file (CSV, JSON, Parquet) a run takes; a larger one answers 413",
    shown="`67108864` (64 MiB)",
)

QUEUE_HORIZON_S: Final = Tunable(
    "QUEUE_HORIZON_S",
    7 * 86400.0,
    "the queue books at most this far ahead, so that it does not fill the calendar while "
    "others book by hand",
)
QUEUE_FAIR_SHARE_WINDOW_S: Final = Tunable(
    "QUEUE_FAIR_SHARE_WINDOW_S",
    14 * 86400.0,
    "the queue serves first who used the robot least in this past window (and up to the horizon)",
)
QUEUE_LEAD_S: Final = Tunable(
    "QUEUE_LEAD_S",
    120.0,
    "the queue books no slot starting sooner than this from now (time to stage the run)",
)
QUEUE_SLOT_S: Final = Tunable(
    "QUEUE_SLOT_S",
    60,
    "a queued request's booking lasts its program rounded up to a whole number of these",
)
QUEUE_PASS_INTERVAL_S: Final = Tunable(
    "QUEUE_PASS_INTERVAL_S",
    60.0,
    "beat's pass of the queue's allocator (a request, a freed slot or a resume wakes it too)",
)
TIMELINE_SNAP_MIN: Final = Tunable(
    "TIMELINE_SNAP_MIN",
    5,
    "a drag on the timeline starts and ends on a multiple of these minutes",
)

TUNABLES: Final[tuple[Tunable[int] | Tunable[float], ...]] = (
    RUN_SWEEP_INTERVAL_S,
    COLLECTOR_SCAN_INTERVAL_S,
    COLLECTOR_WAIT_S,
    RUN_STAGE_LEAD_S,
    RUN_REPEAT_LEAD_S,
    RUN_START_GRACE_S,
    RUN_COLLECT_GRACE_S,
    RESERVATION_REMINDER_LEAD_S,
    SCHEDULER_SYNC_INTERVAL_S,
    SCHEDULER_ORPHAN_GRACE_S,
    DRY_RUN_SLOTS,
    DRY_RUN_MAX_WAITING,
    DRY_RUN_STALE_S,
    DRY_RUN_KEEP_S,
    SELF_CHECK_LEAD_S,
    SELF_CHECK_LAP_M,
    HEALTH_POLL_INTERVAL_S,
    HEALTH_UNREACHABLE_S,
    HEALTH_LOW_BATTERY_V,
    RESERVATION_MAX_S,
    STAFF_API_TOKEN_DAYS,
    DOWNLOADS_IN_FLIGHT_MAX,
    DOWNLOAD_SLOT_S,
    IDEMPOTENCY_KEY_TTL_S,
    WEBHOOK_RETRY_FIRST_S,
    WEBHOOK_RETRY_MAX_S,
    WEBHOOK_RETRY_FOR_S,
    WEBHOOKS_PER_USER_MAX,
    MEASUREMENT_MAX_UPLOAD_BYTES,
    QUEUE_HORIZON_S,
    QUEUE_FAIR_SHARE_WINDOW_S,
    QUEUE_LEAD_S,
    QUEUE_SLOT_S,
    QUEUE_PASS_INTERVAL_S,
    TIMELINE_SNAP_MIN,
)


def readme_table() -> str:
    """The README's "Timings and limits" table, as ``python -m portal.conf`` prints it."""
    rows = ["| variable | default | meaning |", "| --- | --- | --- |"]
    rows += [tunable.readme_row() for tunable in TUNABLES]
    return "\n".join(rows)


if __name__ == "__main__":
    print(readme_table())
