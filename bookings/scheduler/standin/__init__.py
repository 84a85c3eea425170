"""A stand-in for the testbed's omf_sfa broker: the lease subset of its "AM" REST API.

``python -m bookings.scheduler.standin --host 127.0.0.1 --port 8710`` serves it with
waitress. ``make run`` uses it as the embedded scheduler and the tests start it as a
separate process. It behaves as the broker does, quirks included, and each quirk that
deployments differ on is a switch (flag, or ``SCHEDULER_STANDIN_*`` variable):

- ``--conflict-as 401|409|zombie``: a clash with another lease is a 401 "Reservation for
  the resource 'X' failed…" (omf_sfa), a 409, or a 200 with a ``pending`` lease that holds
  no component (older omf_sfa; a clashing move is then omf_sfa's 400).
- ``--granularity-s N``: lease times must fall on multiples of N seconds (else 422).
- ``--empty-as-404``: an empty listing is 404 "No resources matching the request.".
- ``--token``/``--token-file``: every ``/resources`` call needs ``Authorization: Bearer``.
- ``--nodes``: the leasable nodes (default ``node-01`` … ``node-24``).
- ``--db PATH``: keep leases in a SQLite file across restarts (default: memory).
- ``--test-control``: ``/_standin/…`` endpoints that move the clock, inject faults (slow
  answers, 503) and reset everything. Never on in a deployment.

A lease made without a clash is ``accepted``; its status then follows the clock
(``active`` from its start, ``past`` from its end). Overlap is half-open and only
``accepted``/``active`` leases hold nodes. Like omf_sfa, components it does not know are
left out of the lease without a word. Every error is ``{"exception": {"code", "reason"}}``.

The parts: ``config`` (the switches, ``StandinConfig``), ``store`` (the leases, in memory or
in SQLite), ``broker`` (what the broker does with a call, its refusals, the test-only faults
and clock), ``app`` (the Flask app: routes, hooks, the error envelope) and ``__main__`` (the
process under waitress). The names other code imports from the package are re-exported here.
Docs: docs/integration.md.
"""

from bookings.scheduler.standin.app import close_app, create_app
from bookings.scheduler.standin.config import (
    ENV_PREFIX,
    ConfigError,
    StandinConfig,
    build_parser,
    config_from,
)

__all__ = [
    "ENV_PREFIX",
    "ConfigError",
    "StandinConfig",
    "build_parser",
    "close_app",
    "config_from",
    "create_app",
]
