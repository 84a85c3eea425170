"""``amazing events``: your events in order (reservations made, moved, decided, cancelled; each
run's every state and its data ready), and with ``--follow`` as they happen, from
``GET /api/v1/events/``."""

from __future__ import annotations

import json
from collections.abc import Iterator
from datetime import datetime
from typing import Annotated, Any

import typer

from amazing_cli.api import Api
from amazing_cli.commands._common import JsonOption, out, portal_api, reports_errors
from amazing_cli.errors import bad_input

# How long one request waits for an event when following (the portal's most).
WAIT_S = 20.0
RUN_ENDS = {f"run.{state}" for state in ("completed", "interrupted", "failed", "cancelled")}


def events_page(
    api: Api,
    *,
    after: int,
    wait_s: float,
    types: list[str] | None = None,
    subject: str | None = None,
) -> dict[str, Any]:
    """One answer of ``GET /api/v1/events/``: the events after ``after`` (waiting up to
    ``wait_s`` for the first) and ``last``, where to go on from."""
    params: dict[str, Any] = {"after": after, "limit": 500, "wait": wait_s}
    if types:
        params["type"] = types
    if subject:
        params["subject"] = subject
    return api.call("events", params=params)


def event_stream(
    api: Api,
    *,
    after: int,
    follow: bool,
    types: list[str] | None = None,
    subject: str | None = None,
) -> Iterator[dict[str, Any]]:
    """The events after ``after``, oldest first; following, it waits for more for ever."""
    while True:
        page = events_page(
            api, after=after, wait_s=WAIT_S if follow else 0, types=types, subject=subject
        )
        yield from page["events"]
        after = page["last"]
        if not follow and not page["events"]:
            return


def describe(event: dict[str, Any]) -> str:
    """One line for a person: when, what, about what, and the gist of the payload."""
    when = datetime.fromisoformat(event["occurred_at"]).astimezone().strftime("%Y-%m-%d %H:%M:%S")
    data = event["data"]
    if event["type"].startswith("reservation."):
        start = datetime.fromisoformat(data["start_at"]).astimezone().strftime("%Y-%m-%d %H:%M")
        end = datetime.fromisoformat(data["end_at"]).astimezone().strftime("%H:%M")
        door = f" via {data['via']}" if data.get("via") else ""
        by = f" by {data['by']}" if data.get("by") else ""
        gist = f"{', '.join(data['resources'])} {start}–{end}, {data['state']}{by}{door}"
    elif event["type"] == "run.data_ready":
        missing = f", {data['missing']} stretches missing" if data["missing"] else ""
        gist = (
            f"{data['resource']} {data['state']}: {data['samples']} samples{missing}; "
            f"`amazing download {data['run']}`"
        )
    elif event["type"].startswith("run."):
        reason = f": {data['reason']}" if data.get("reason") else ""
        gist = f"{data['resource']} {data['from_state'] or '∅'} → {data['state']}{reason}"
    else:
        gist = json.dumps(data, sort_keys=True)
    return f"#{event['id']} {when} {event['type']} {event['subject']} {gist}"


@reports_errors
def events(
    ctx: typer.Context,
    after: Annotated[
        int, typer.Option(metavar="ID", min=0, help="Start after this event's id (0: the oldest).")
    ] = 0,
    follow: Annotated[
        bool, typer.Option("--follow", "-f", help="Keep waiting for new events.")
    ] = False,
    run: Annotated[
        int | None,
        typer.Option(
            metavar="RUN", help="Only this run's events; following, stop once it has ended."
        ),
    ] = None,
    type: Annotated[
        list[str] | None,
        typer.Option("--type", metavar="TYPE", help="Only events of this type (repeatable)."),
    ] = None,
    as_json: JsonOption = False,
) -> None:
    """Your events, oldest first: one line each, or with `--json` one JSON object per line."""
    if run is not None and run < 1:
        raise bad_input(f"--run {run}: give a run's id")
    api = portal_api(ctx)
    subject = f"run:{run}" if run is not None else None

    def show(event: dict[str, Any]) -> None:
        if as_json:
            out.print(json.dumps(event, sort_keys=True), markup=False, highlight=False)
        else:
            out.print(describe(event), markup=False)

    for event in event_stream(api, after=after, follow=follow, types=type, subject=subject):
        show(event)
        if subject is not None and event["type"] in RUN_ENDS:
            # What its ending wrote with it (its data ready) is there already: shown, then done.
            for rest in event_stream(
                api, after=event["id"], follow=False, types=type, subject=subject
            ):
                show(rest)
            return
