"""Booking the robot: ``amazing book`` (and ``--again``, ``--check``), ``cancel`` and
``attach``."""

from __future__ import annotations

from datetime import timedelta
from typing import Annotated, Any

import typer

from amazing_cli import times
from amazing_cli.api import Api
from amazing_cli.commands._common import (
    JsonOption,
    QuietOption,
    err,
    out,
    portal_api,
    print_json,
    reports_errors,
)
from amazing_cli.commands.resources import first_slot
from amazing_cli.errors import REFUSED, bad_input

# Added to a program's length when no --duration is given: the robot's last ramp down.
BOOKING_MARGIN_S = 5


def _only_mobile(api: Api) -> str:
    mobiles = [r["name"] for r in api.call("resources") if r["kind"] == "mobile"]
    if len(mobiles) != 1:
        raise bad_input(
            "name the robot to book: " + (", ".join(mobiles) if mobiles else "there is none")
        )
    return mobiles[0]


@reports_errors
def book(
    ctx: typer.Context,
    experiment: Annotated[
        int | None,
        typer.Option("--experiment", "-e", metavar="ID", help="The experiment the robot runs."),
    ] = None,
    resource: Annotated[
        str | None,
        typer.Argument(metavar="ROBOT", help="The robot to book; default: the only one."),
    ] = None,
    start: Annotated[
        str,
        typer.Option(
            metavar="WHEN",
            help="When: `asap` (the first free slot), RFC 3339 (2026-05-01T10:00+01:00) or "
            "relative (+30m).",
        ),
    ] = "asap",
    duration: Annotated[
        float | None,
        typer.Option(
            metavar="SECONDS",
            min=1,
            help="Seconds to book; default: the experiment's length and a margin.",
        ),
    ] = None,
    node: Annotated[
        list[str] | None,
        typer.Option(metavar="NODE", help="A fixed node to book with it (repeat for more)."),
    ] = None,
    title: Annotated[
        str | None, typer.Option(metavar="TITLE", help="Default: the experiment's title.")
    ] = None,
    after: Annotated[
        int | None,
        typer.Option(
            metavar="RUN", help="Start when this run's booking ends: back to back with it."
        ),
    ] = None,
    lead: Annotated[
        float,
        typer.Option(
            metavar="SECONDS", min=0, help="With `asap`: start no sooner than this many seconds."
        ),
    ] = 15,
    check: Annotated[
        bool,
        typer.Option(
            "--check",
            help="Book nothing: say whether the booking would be made, and every reason it "
            "would not (exit code 3).",
        ),
    ] = False,
    again: Annotated[
        int | None,
        typer.Option(
            "--again",
            metavar="RUN",
            help="Run this run again: its program and limits on its robot, in the next free "
            "slot of its length. The new run links to it.",
        ),
    ] = None,
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Book a robot (and fixed nodes) to run an experiment, or run a run again."""
    if again is not None:
        _book_again(
            ctx,
            again,
            given={
                "--experiment": experiment is not None,
                "ROBOT": resource is not None,
                "--start": start != "asap",
                "--duration": duration is not None,
                "--node": bool(node),
                "--title": title is not None,
                "--after": after is not None,
                "--check": check,
            },
            as_json=as_json,
            quiet=quiet,
        )
        return
    if experiment is None:
        raise bad_input("give --experiment ID (or --again RUN)")
    api = portal_api(ctx)
    body = _booking(
        api,
        experiment,
        resource,
        node or [],
        start=start,
        after=after,
        duration=duration,
        lead=lead,
    )
    if check:
        _check(api, body, as_json=as_json, quiet=quiet)
        return
    if title:
        body["title"] = title
    _book(api, body, as_json=as_json, quiet=quiet)


def _booking(
    api: Api,
    experiment: int,
    robot: str | None,
    nodes: list[str],
    *,
    start: str,
    after: int | None,
    duration: float | None,
    lead: float,
) -> dict[str, Any]:
    """What ``book`` asks the portal for: the resources, the experiment and the slot."""
    program = api.call("experiment", path={"id": experiment})
    names = [robot or _only_mobile(api), *nodes]
    length = timedelta(seconds=duration or times.ceil_s(program["duration_s"]) + BOOKING_MARGIN_S)
    if after is not None:
        if start != "asap":
            raise bad_input("give --start or --after, not both")
        begin = times.parse_api(api.call("run", path={"id": after})["end_at"])
        end = begin + length
    elif start == "asap":
        begin, end = first_slot(
            api, names, earliest=times.now() + timedelta(seconds=lead), length=length
        )
    else:
        begin = times.parse_instant(start, option="--start")
        end = begin + length
    return {
        "resources": names,
        "experiment": experiment,
        "start_at": times.iso(begin),
        "end_at": times.iso(end),
    }


def _book(api: Api, body: dict[str, Any], *, as_json: bool, quiet: bool) -> None:
    """Book ``body`` and say what was booked."""
    booked = api.create("reservation_create", body)
    run = booked.get("run")
    if as_json:
        print_json(booked)
    elif quiet:
        out.print(run["id"] if run else booked["id"])
    else:
        what = f"run {run['id']} of experiment {body['experiment']}" if run else "no run"
        out.print(
            f"Booked reservation {booked['id']} ({what}): {', '.join(booked['resources'])}, "
            f"{times.local(booked['start_at'])} to {times.local(booked['end_at'])}, "
            f"{booked['state']}."
        )


def _book_again(
    ctx: typer.Context, run: int, *, given: dict[str, bool], as_json: bool, quiet: bool
) -> None:
    """``book --again RUN``: the portal finds the slot and books it (``POST …/again/``)."""
    extra = [name for name, present in given.items() if present]
    if extra:
        raise bad_input(
            f"--again takes the run's own program, robot and length: drop {', '.join(extra)}"
        )
    booked = portal_api(ctx).create("run_again", path={"id": run})
    new_run = booked.get("run") or {}
    if as_json:
        print_json(booked)
    elif quiet:
        out.print(new_run.get("id", booked["id"]))
    else:
        out.print(
            f"Booked reservation {booked['id']} (run {new_run.get('id')}, repeating run {run}): "
            f"{', '.join(booked['resources'])}, {times.local(booked['start_at'])} to "
            f"{times.local(booked['end_at'])}, {booked['state']}."
        )


def _check(api: Api, body: dict[str, Any], *, as_json: bool, quiet: bool) -> None:
    """The portal's live check of ``body``: exit code 0 when it would be booked, else 3."""
    answer = api.call("reservation_check", json=body)
    if answer.get("notice"):
        err.print(f"amazing: {answer['notice']}", markup=False)
    if as_json:
        print_json(answer)
    elif not quiet and answer["fits"]:
        wait = " (an admin must approve it)" if answer.get("needs_approval") else ""
        out.print(
            f"Would be booked{wait}: {', '.join(body['resources'])}, "
            f"{times.local(body['start_at'])} to {times.local(body['end_at'])}."
        )
    elif not quiet:
        for problem in answer["problems"]:
            messages = answer["quota"] if problem["code"] == "quota" else [problem["message"]]
            for message in messages:
                out.print(f"{problem['code']}: {message}", markup=False)
    if not answer["fits"]:
        raise typer.Exit(REFUSED)


@reports_errors
def cancel(
    ctx: typer.Context,
    run: Annotated[
        int | None, typer.Argument(metavar="RUN", help="The run whose booking to cancel.")
    ] = None,
    reservation: Annotated[
        int | None,
        typer.Option(metavar="ID", help="Or the reservation itself (e.g. fixed nodes only)."),
    ] = None,
    reason: Annotated[
        str, typer.Option(metavar="TEXT", help="Why (needed when an admin cancels).")
    ] = "",
    as_json: JsonOption = False,
) -> None:
    """Cancel a booking and its run."""
    if (run is None) == (reservation is None):
        raise bad_input("give a run, or --reservation, not both")
    api = portal_api(ctx)
    if reservation is None:
        reservation = api.call("run", path={"id": run})["reservation"]
    cancelled = api.call(
        "reservation_cancel",
        path={"id": reservation},
        params={"reason": reason} if reason else None,
    )
    if as_json:
        print_json(cancelled)
    else:
        out.print(f"Reservation {cancelled['id']} is {cancelled['state']}.")


@reports_errors
def attach(
    ctx: typer.Context,
    reservation: Annotated[
        int,
        typer.Argument(
            metavar="RESERVATION", help="A booking made through the testbed scheduler's lease API."
        ),
    ],
    experiment: Annotated[
        int,
        typer.Option("--experiment", "-e", metavar="ID", help="The experiment the robot runs."),
    ],
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Give a booking made through the lease API the experiment its robot runs, before it
    starts (checked as booking checks it)."""
    attached = portal_api(ctx).create(
        "reservation_attach", {"experiment": experiment}, path={"id": reservation}
    )
    run = attached["run"]
    if as_json:
        print_json(attached)
    elif quiet:
        out.print(run["id"])
    else:
        out.print(
            f"Reservation {attached['id']} runs experiment {experiment} as run {run['id']}: "
            f"{', '.join(attached['resources'])}, {times.local(attached['start_at'])} to "
            f"{times.local(attached['end_at'])}."
        )
