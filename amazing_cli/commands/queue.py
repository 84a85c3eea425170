"""``amazing queue …``: runs asked for "as soon as possible" (``/api/v1/queue/``): ask, see
each request's place and estimated start, withdraw one."""

from __future__ import annotations

import re
from typing import Annotated, Any

import typer

from amazing_cli import times
from amazing_cli.commands._common import (
    JsonOption,
    QuietOption,
    out,
    portal_api,
    print_json,
    reports_errors,
)
from amazing_cli.errors import bad_input

RequestId = Annotated[int, typer.Argument(metavar="ID", min=1, help="The request's id.")]
HOURS = re.compile(r"^(\d{1,2})-(\d{1,2})$")


def _hours(text: str | None) -> tuple[int | None, int | None]:
    if text is None:
        return None, None
    found = HOURS.match(text.strip())
    if not found:
        raise bad_input(f"--hours {text!r}: give FROM-TO in the testbed's hours, such as 22-6")
    return int(found[1]), int(found[2])


def _where(request: dict[str, Any]) -> str:
    if request["state"] == "booked":
        return f"booked (reservation {request['reservation']}) from " + times.local(
            request["estimated_start_at"]
        )
    if request["state"] != "waiting":
        return f"{request['state']}: {request['reason']}"
    estimate = request["estimated_start_at"]
    place = f"waiting, place {request['position']}"
    place += f", estimated start {times.local(estimate)}" if estimate else ", no slot yet"
    return place + (f" ({request['reason']})" if request["reason"] else "")


@reports_errors
def queue_list(
    ctx: typer.Context,
    every: Annotated[
        bool, typer.Option("--all", help="Also requests booked, expired or cancelled.")
    ] = False,
    as_json: JsonOption = False,
) -> None:
    """Your requests: each one's place in the queue and estimated start."""
    listed = [r for r in portal_api(ctx).pages("queue") if every or r["state"] == "waiting"]
    if as_json:
        print_json(listed)
        return
    if not listed:
        out.print("Nothing waiting: `amazing queue add EXPERIMENT --by WHEN` asks for a run.")
        return
    for request in listed:
        out.print(
            f"{request['id']}  {request['title']} on {request['robot']}: {_where(request)}",
            markup=False,
        )


@reports_errors
def queue_add(
    ctx: typer.Context,
    experiment: Annotated[int, typer.Argument(metavar="EXPERIMENT", help="Its id.")],
    by: Annotated[
        str,
        typer.Option(
            metavar="WHEN", help="The latest end: RFC 3339 or relative (+2d); expires after."
        ),
    ],
    robot: Annotated[str, typer.Option(metavar="ROBOT", help="The robot.")] = "mobile-1",
    earliest: Annotated[
        str | None, typer.Option(metavar="WHEN", help="No sooner than this (default: now).")
    ] = None,
    duration: Annotated[
        int | None,
        typer.Option(metavar="SECONDS", min=1, help="Default: the program, to a whole minute."),
    ] = None,
    hours: Annotated[
        str | None,
        typer.Option(metavar="FROM-TO", help="Allowed hours of the testbed's day (22-6: nights)."),
    ] = None,
    node: Annotated[
        list[str] | None,
        typer.Option(metavar="NODE", help="A fixed node held with it (repeat for more)."),
    ] = None,
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Ask for a run as soon as possible: the queue books the first slot that fits."""
    hours_from, hours_to = _hours(hours)
    body: dict[str, Any] = {
        "experiment": experiment,
        "robot": robot,
        "nodes": node or [],
        "latest_end_at": times.iso(times.parse_instant(by, option="--by")),
        "hours_from": hours_from,
        "hours_to": hours_to,
    }
    if earliest is not None:
        body["earliest_at"] = times.iso(times.parse_instant(earliest, option="--earliest"))
    if duration is not None:
        body["duration_s"] = duration
    made = portal_api(ctx).create("queue_create", body)
    if as_json:
        print_json(made)
    elif quiet:
        out.print(made["id"])
    else:
        out.print(f"Queued request {made['id']}: {_where(made)}.", markup=False)


@reports_errors
def queue_cancel(
    ctx: typer.Context,
    request_id: RequestId,
    reason: Annotated[str, typer.Option(metavar="TEXT", help="Why (kept with it).")] = "",
    as_json: JsonOption = False,
) -> None:
    """Withdraw a waiting request."""
    cancelled = portal_api(ctx).call(
        "queue_cancel", path={"id": request_id}, json={"reason": reason}
    )
    if as_json:
        print_json(cancelled)
    else:
        out.print(f"Request {request_id} withdrawn.")
