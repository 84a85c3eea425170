"""The one check the schemathesis run adds, loaded by schemathesis itself (``hooks``).

``positive_data_acceptance`` (a schema-valid request must not be refused with 400) is replaced,
for the operations of :data:`DATA_DEPENDENT_FIELDS` and :data:`DATA_DEPENDENT_ERRORS` only, by
:func:`refused_only_for_stated_reasons`. Their requests must meet conditions that JSON Schema
cannot state: they name stored things (resources, users, a robot's limits), compare fields
with each other or with the clock (an end after its start, a start in the future), or depend
on the run (its rail's length). A schema-valid request may be refused there only with 400
naming a field listed for that operation, or with 400 or 422 carrying an error code listed for
it. No Django here: schemathesis runs apart.
"""

from __future__ import annotations

from typing import Any

import schemathesis

DATA_DEPENDENT_FIELDS: dict[tuple[str, str], frozenset[str]] = {
    # end after start, at most 62 days later
    ("GET", "/api/v1/resources/{name}/availability/"): frozenset({"end"}),
    ("GET", "/api/v1/reservations/busy/"): frozenset({"end"}),
    # resource and user names, the experiment against the robot (its velocities, its length
    # against the slot's), the slot (in the future, not too long, robot in service), the
    # fields only admins may give
    ("POST", "/api/v1/reservations/"): frozenset(
        {"resources", "resource", "owner", "start_at", "end_at", "experiment", "override_reason"}
    ),
    ("PATCH", "/api/v1/reservations/{id}/"): frozenset(
        {"resources", "start_at", "end_at", "experiment"}
    ),
    # an admin cancelling someone else's booking says why
    ("DELETE", "/api/v1/reservations/{id}/"): frozenset({"reason"}),
    # a rejection says why
    ("POST", "/api/v1/reservations/{id}/decision/"): frozenset({"reason"}),
    ("POST", "/api/v1/reservations/check/"): frozenset({"resources"}),
    ("POST", "/api/v1/quota/check/"): frozenset({"resources"}),  # its deprecated name
    # resource names; the window's end after its start, its start not long past; some
    # resources, or all of them
    ("POST", "/api/v1/blackouts/"): frozenset({"resources", "start_at", "end_at"}),
    # users, groups and resources by name; a limit in hours or count needs a period
    ("POST", "/api/v1/quota-policies/"): frozenset(
        {"user", "group", "resource", "resource_group", "period"}
    ),
    ("PATCH", "/api/v1/quota-policies/{id}/"): frozenset(
        {"user", "group", "resource", "resource_group", "period"}
    ),
    # velocities within the limit of a robot the author may book; the program's total length
    ("POST", "/api/v1/experiments/"): frozenset({"segments"}),
    ("PUT", "/api/v1/experiments/{id}/"): frozenset({"segments"}),
    # the position must be on this run's rail
    ("GET", "/api/v1/runs/{id}/analysis/"): frozenset({"pass_at_m"}),
    # a measurement file must read as points near the run's time, into a series of a slug's
    # name with those columns; a batch's points likewise; an offset within a day
    ("POST", "/api/v1/runs/{id}/measurements/"): frozenset(
        {"file", "name", "format", "columns", "time_column", "clock_offset_s"}
    ),
    ("POST", "/api/v1/runs/{id}/measurements/{name}/"): frozenset({"points", "name"}),
    ("PATCH", "/api/v1/runs/{id}/measurements/{name}/"): frozenset({"clock_offset_s"}),
    # a fixed node has no robot; the robot's own velocity limit
    ("GET", "/api/v1/resources/{name}/robot/"): frozenset({"resource"}),
    ("POST", "/api/v1/resources/{name}/robot/control/"): frozenset({"resource", "velocity_mps"}),
    ("POST", "/api/v1/resources/{name}/robot/stop/"): frozenset({"resource"}),
    ("POST", "/api/v1/resources/{name}/robot/release/"): frozenset({"resource"}),
    ("GET", "/api/v1/resources/{name}/robot/logs/{day}/"): frozenset({"resource"}),
    # a URL whose name resolves, to an address the deployment allows; staff's event types
    # only with staff_events, which is staff's
    ("POST", "/api/v1/webhooks/"): frozenset({"url", "types", "staff_events"}),
    ("PATCH", "/api/v1/webhooks/{id}/"): frozenset({"url", "types"}),
    # a fixed node has no rail
    ("GET", "/api/v1/resources/{name}/rail/"): frozenset({"resource"}),
    # the list's last day on or after its first
    ("GET", "/api/v1/runs/"): frozenset({"started_to"}),
    # a robot and nodes by name, the experiment's length within the duration and its
    # velocities within the robot's limit, room for the run between the earliest start and
    # the latest end, both allowed hours or neither
    ("POST", "/api/v1/queue/"): frozenset(
        {"robot", "nodes", "experiment", "duration_s", "latest_end_at", "hours_to"}
    ),
    # a campaign file: the robot and nodes by name, each parameter's values (JSON Schema
    # cannot say what a sweep holds), not too many runs, each run's program and its room
    # between the earliest start and the latest end, the allowed hours
    ("POST", "/api/v1/campaigns/"): frozenset(
        {
            "robot",
            "nodes",
            "parameters",
            "velocity_mps",
            "direction",
            "duration_s",
            "latest_end_at",
            "hours",
            "hours_to",
            "repeats",
            "seed",
            "title",
            "segments",
            "experiment",
        }
    ),
    # a pause and a reordering say why
    ("POST", "/api/v1/queue/pause/"): frozenset({"reason"}),
    ("POST", "/api/v1/queue/{id}/reorder/"): frozenset({"reason"}),
}

# Refusals of a schema-valid request by what it names that is stored, by their error code
# alone: a user's name and password (which of the two is wrong is not told), an idempotency
# key's earlier use for another request (422, documented on the operation).
_KEY_REUSED = frozenset({"idempotency_key_reused"})
DATA_DEPENDENT_ERRORS: dict[tuple[str, str], frozenset[str]] = {
    ("POST", "/api/v1/auth/token/"): frozenset({"sign_in_failed"}),
    ("POST", "/api/v1/reservations/"): _KEY_REUSED,
    ("POST", "/api/v1/reservations/{id}/attach/"): _KEY_REUSED,
    ("POST", "/api/v1/runs/{id}/again/"): _KEY_REUSED,
    ("POST", "/api/v1/queue/"): _KEY_REUSED,
    ("POST", "/api/v1/campaigns/"): _KEY_REUSED,
}

# Every operation whose positive_data_acceptance this module's check replaces.
DATA_DEPENDENT = set(DATA_DEPENDENT_FIELDS) | set(DATA_DEPENDENT_ERRORS)


def _field_root(path: str) -> str:
    """``resources.0`` → ``resources``: list items and nested keys belong to their field."""
    return path.split(".", 1)[0]


@schemathesis.check
def refused_only_for_stated_reasons(ctx: Any, response: Any, case: Any) -> bool | None:
    meta = case.meta
    if meta is None or not meta.generation.mode.is_positive:
        return None
    operation = (case.method.upper(), case.path)
    if operation not in DATA_DEPENDENT or response.status_code not in (400, 422):
        return None  # positive_data_acceptance itself runs on the other operations
    try:
        body = response.json()
    except ValueError:
        body = {}
    body = body if isinstance(body, dict) else {}
    if body.get("error") in DATA_DEPENDENT_ERRORS.get(operation, ()):
        return None
    allowed = DATA_DEPENDENT_FIELDS.get(operation, frozenset())
    fields = {_field_root(name) for name in body.get("fields", {})}
    if response.status_code != 400:
        fields = set()  # only a 400 refuses for a field
    unexpected = (fields - allowed) if fields else {"(no field named)"}
    if unexpected:
        raise AssertionError(
            f"A schema-valid request was refused for {sorted(unexpected)}, which the schema "
            f"could state: {response.text[:300]}"
        )
    return None
