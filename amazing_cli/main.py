"""The ``amazing`` command: book the mobile node, run experiments, get their data.

Everything goes through the portal's public REST API (:mod:`amazing_cli.api`). Output is for
people by default; ``--json`` prints the API's JSON for scripts and ``--quiet`` only the id a
command made. Exit codes: 0 ok, 2 bad input, 3 refused, 4 not found, 5 server or network
(``watch``: 1 when the run ended without completing). ``docs/cli.md`` is the manual.
"""

from __future__ import annotations

import functools
import json
import os
import socket
import sys
import time
from collections.abc import Callable, Iterator
from datetime import datetime, timedelta
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    DownloadColumn,
    Progress,
    SpinnerColumn,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TransferSpeedColumn,
)
from rich.table import Table

from amazing_cli import config, programs, times
from amazing_cli.api import Api
from amazing_cli.errors import (
    NOT_FOUND,
    OK,
    REFUSED,
    RUN_NOT_COMPLETED,
    UNAVAILABLE,
    CliError,
    bad_input,
)
from amazing_cli.package import read_package

RUN_END_STATES = ("completed", "cancelled", "failed", "interrupted")
# Added to a program's length when no --duration is given: the robot's last ramp down.
BOOKING_MARGIN_S = 5
AVAILABILITY_WINDOW = timedelta(days=62) - timedelta(seconds=1)

app = typer.Typer(
    name="amazing",
    help="Book the AMazING testbed's mobile node, run experiments on it and get their data.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
experiment_app = typer.Typer(help="Experiments: the programs the robot runs.", no_args_is_help=True)
app.add_typer(experiment_app, name="experiment")

out = Console(highlight=False, soft_wrap=True)
err = Console(stderr=True, highlight=False, soft_wrap=True)

JsonOption = Annotated[bool, typer.Option("--json", help="Print the API's JSON, for scripts.")]
QuietOption = Annotated[
    bool, typer.Option("--quiet", "-q", help="Print only the id of what was made.")
]

F = TypeVar("F", bound=Callable[..., Any])


def reports_errors(command: F) -> F:
    """One clear line on stderr and the documented exit code, for any problem."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except CliError as exc:
            err.print(f"amazing: {exc.message}", markup=False)
            raise typer.Exit(exc.exit_code) from None
        except KeyboardInterrupt:
            err.print("amazing: interrupted", markup=False)
            raise typer.Exit(130) from None

    return wrapper  # type: ignore[return-value]


def _api(ctx: typer.Context, *, authenticated: bool = True) -> Api:
    options = ctx.find_root().obj or {}
    credentials = config.load(url=options.get("url"), token=options.get("token"))
    token = config.require_token(credentials) if authenticated else credentials.token
    return Api(credentials.url, token)


def _print_json(value: Any) -> None:
    out.print_json(json.dumps(value), highlight=False)


@app.callback()
def root(
    ctx: typer.Context,
    url: Annotated[
        str | None,
        typer.Option(
            metavar="URL", help="The portal's address (else AMAZING_URL, else the stored login)."
        ),
    ] = None,
    token: Annotated[
        str | None,
        typer.Option(
            metavar="TOKEN", help="An API token (else AMAZING_TOKEN, else the stored login)."
        ),
    ] = None,
) -> None:
    ctx.obj = {"url": url, "token": token}


# --- login ----------------------------------------------------------------------------------


@app.command()
@reports_errors
def login(
    ctx: typer.Context,
    url: Annotated[str | None, typer.Option(metavar="URL", help="The portal's address.")] = None,
    token: Annotated[
        str | None, typer.Option(metavar="TOKEN", help="An API token made on the portal's page.")
    ] = None,
    username: Annotated[
        str | None,
        typer.Option(metavar="NAME", help="Sign in with your username (or email) and password."),
    ] = None,
    code: Annotated[
        str | None,
        typer.Option(metavar="CODE", help="Your two-factor code (asked for when needed)."),
    ] = None,
    name: Annotated[
        str | None,
        typer.Option(metavar="NAME", help="The new token's name (default: amazing on HOST)."),
    ] = None,
    expires_in_days: Annotated[
        int | None,
        typer.Option(metavar="DAYS", help="The new token expires after DAYS (default: never)."),
    ] = None,
    as_json: JsonOption = False,
) -> None:
    """Sign in and store a token for the next commands (mode 0600).

    With --username, the portal makes a new token for this computer (password from
    AMAZING_PASSWORD or asked for; the two-factor code too, if the account has one).
    Otherwise, paste a token made on the portal's "API tokens" page."""
    current = config.load(url=url or ctx.find_root().obj.get("url"))
    if username is not None:
        token = _sign_in(current.url, username, code, name, expires_in_days)
    elif token is None:
        token = os.environ.get("AMAZING_TOKEN") or typer.prompt(
            f"API token for {current.url}", hide_input=True
        )
    token = token.strip()
    if not token:
        raise bad_input("the token is empty")
    me = Api(current.url, token).call("me")
    path = config.save(url=current.url, token=token)
    if as_json:
        _print_json({**me, "url": current.url, "stored_in": str(path)})
        return
    role = " (admin)" if me.get("is_admin") else ""
    out.print(f"Logged in to {current.url} as {me['username']}{role}; token stored in {path}.")


def _sign_in(
    url: str, username: str, code: str | None, name: str | None, expires_in_days: int | None
) -> str:
    """A new token from the portal for ``username``'s password (and two-factor code)."""
    password = os.environ.get("AMAZING_PASSWORD") or typer.prompt(
        f"Password of {username} on {url}", hide_input=True
    )
    body: dict[str, Any] = {
        "username": username,
        "password": password,
        "code": code or "",
        "name": name or f"amazing on {socket.gethostname()}"[:100],
        "expires_in_days": expires_in_days,
    }
    api = Api(url, None)
    try:
        answer = api.call("token_sign_in", json=body)
    except CliError as exc:
        if exc.error != "mfa_required" or code:
            raise
        body["code"] = typer.prompt("Two-factor code").strip()
        answer = api.call("token_sign_in", json=body)
    return str(answer["token"])


@app.command()
@reports_errors
def logout() -> None:
    """Revoke the stored token on the portal and forget it."""
    stored = config.stored_credentials()
    revoked = False
    if stored is not None:
        try:
            Api(stored.url, stored.token).call("token_revoke")
            revoked = True
        except CliError as exc:
            if exc.status != 401:  # already revoked or expired: forgetting it is enough
                raise
    forgotten = config.forget()
    if not forgotten:
        out.print("No token was stored.")
    else:
        out.print("Token revoked and forgotten." if revoked else "Token forgotten.")


# --- what there is --------------------------------------------------------------------------


@app.command()
@reports_errors
def resources(ctx: typer.Context, as_json: JsonOption = False) -> None:
    """The robots and fixed nodes."""
    listed = _api(ctx).call("resources")
    if as_json:
        _print_json(listed)
        return
    table = Table("name", "kind", "max velocity", "in service", "approval", box=None)
    for r in listed:
        velocity = f"{r['max_velocity_mps']:g} m/s" if r.get("max_velocity_mps") else "-"
        table.add_row(
            r["name"],
            r["kind"],
            velocity,
            "yes" if r["enabled"] else "no",
            "needed" if r["requires_approval"] else "-",
        )
    out.print(table)


def _free(api: Api, name: str, start: datetime, end: datetime) -> list[tuple[datetime, datetime]]:
    answer = api.call(
        "availability",
        path={"name": name},
        params={"start": times.iso(start), "end": times.iso(end)},
    )
    return [(times.parse_api(f["start"]), times.parse_api(f["end"])) for f in answer["free"]]


@app.command()
@reports_errors
def availability(
    ctx: typer.Context,
    resource: Annotated[
        str, typer.Argument(metavar="RESOURCE", help="A resource's name, e.g. mobile-1.")
    ],
    start: Annotated[
        str,
        typer.Option("--from", metavar="WHEN", help="From when (RFC 3339, or +2h); default now."),
    ] = "+0s",
    days: Annotated[
        float, typer.Option(metavar="DAYS", min=0.01, max=62, help="For how many days.")
    ] = 7,
    as_json: JsonOption = False,
) -> None:
    """When a resource is free."""
    api = _api(ctx)
    begin = times.parse_instant(start, option="--from")
    answer = api.call(
        "availability",
        path={"name": resource},
        params={"start": times.iso(begin), "end": times.iso(begin + timedelta(days=days))},
    )
    if as_json:
        _print_json(answer)
        return
    if not answer["free"]:
        out.print(
            f"{resource} is not free between {times.local(answer['start'])} and "
            f"{times.local(answer['end'])}."
        )
        return
    table = Table("free from", "until", box=None)
    for interval in answer["free"]:
        table.add_row(times.local(interval["start"]), times.local(interval["end"]))
    out.print(table)


@app.command()
@reports_errors
def quota(ctx: typer.Context, as_json: JsonOption = False) -> None:
    """Your quotas and how much of them you use."""
    answer = _api(ctx).call("quota")
    if as_json:
        _print_json(answer)
        return
    if not answer["policies"]:
        out.print("No quota applies to you.")
        return
    table = Table("policy", "applies to", "period", "used", "limit", box=None)
    for p in answer["policies"]:
        used, limit = [], []
        if p.get("max_hours") is not None:
            used.append(f"{p.get('used_hours', 0):g} h")
            limit.append(f"{p['max_hours']:g} h")
        if p.get("max_count") is not None:
            used.append(f"{p.get('used_count', 0)} bookings")
            limit.append(f"{p['max_count']} bookings")
        if p.get("max_length_s") is not None:
            limit.append(f"{times.seconds(p['max_length_s'])} each")
        if p.get("max_future") is not None:
            limit.append(f"{p['max_future']} upcoming")
        table.add_row(
            p["policy"],
            p["scope"],
            p.get("period") or "-",
            ", ".join(used) or "-",
            ", ".join(limit) or "-",
        )
    out.print(table)


# --- experiments ----------------------------------------------------------------------------


@experiment_app.command("create")
@reports_errors
def experiment_create(
    ctx: typer.Context,
    file: Annotated[
        Path, typer.Argument(metavar="FILE", help="A YAML or JSON file: title and segments.")
    ],
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Create an experiment from a file, checked against the portal's schema first."""
    document = programs.load(file)
    api = _api(ctx)
    body = programs.validate(document, schema=api.schema(), source=file)
    created = api.call("experiment_create", json=body)
    if as_json:
        _print_json(created)
    elif quiet:
        out.print(created["id"])
    else:
        out.print(
            f"Created experiment {created['id']}: {created['title']} "
            f"({len(created['segments'])} segments, {times.seconds(created['duration_s'])})."
        )


@experiment_app.command("list")
@reports_errors
def experiment_list(
    ctx: typer.Context,
    limit: Annotated[
        int, typer.Option(metavar="N", min=1, help="At most this many, newest first.")
    ] = 50,
    as_json: JsonOption = False,
) -> None:
    """Your experiments."""
    listed = list(_api(ctx).pages("experiments", limit=limit))
    if as_json:
        _print_json(listed)
        return
    table = Table("id", "title", "segments", "lasts", "created", box=None)
    for e in listed:
        table.add_row(
            str(e["id"]),
            e["title"],
            str(len(e["segments"])),
            times.seconds(e["duration_s"]),
            times.local(e["created_at"]),
        )
    out.print(table)


# --- booking --------------------------------------------------------------------------------


def _only_mobile(api: Api) -> str:
    mobiles = [r["name"] for r in api.call("resources") if r["kind"] == "mobile"]
    if len(mobiles) != 1:
        raise bad_input(
            "name the robot to book: " + (", ".join(mobiles) if mobiles else "there is none")
        )
    return mobiles[0]


def _intersect(
    a: list[tuple[datetime, datetime]], b: list[tuple[datetime, datetime]]
) -> list[tuple[datetime, datetime]]:
    both = []
    for start_a, end_a in a:
        for start_b, end_b in b:
            start, end = max(start_a, start_b), min(end_a, end_b)
            if start < end:
                both.append((start, end))
    return sorted(both)


def _first_slot(
    api: Api, names: list[str], *, earliest: datetime, length: timedelta
) -> tuple[datetime, datetime]:
    """The first time from ``earliest`` at which every resource is free for ``length``."""
    window_end = earliest + AVAILABILITY_WINDOW
    free = _free(api, names[0], earliest, window_end)
    for name in names[1:]:
        free = _intersect(free, _free(api, name, earliest, window_end))
    for start, end in free:
        start = times.next_second(start)
        if end - start >= length:
            return start, start + length
    raise CliError(
        f"no free slot of {times.seconds(length.total_seconds())} for {', '.join(names)} in the "
        "next 62 days",
        exit_code=NOT_FOUND,
    )


@app.command()
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
    api = _api(ctx)
    program = api.call("experiment", path={"id": experiment})
    robot = resource or _only_mobile(api)
    names = [robot, *(node or [])]
    length = timedelta(seconds=duration or times.ceil_s(program["duration_s"]) + BOOKING_MARGIN_S)
    if after is not None:
        if start != "asap":
            raise bad_input("give --start or --after, not both")
        begin = times.parse_api(api.call("run", path={"id": after})["end_at"])
        end = begin + length
    elif start == "asap":
        begin, end = _first_slot(
            api, names, earliest=times.now() + timedelta(seconds=lead), length=length
        )
    else:
        begin = times.parse_instant(start, option="--start")
        end = begin + length
    body: dict[str, Any] = {
        "resources": names,
        "experiment": experiment,
        "start_at": times.iso(begin),
        "end_at": times.iso(end),
    }
    if check:
        _check(api, body, as_json=as_json, quiet=quiet)
        return
    if title:
        body["title"] = title
    booked = api.create("reservation_create", body)
    run = booked.get("run")
    if as_json:
        _print_json(booked)
    elif quiet:
        out.print(run["id"] if run else booked["id"])
    else:
        what = f"run {run['id']} of experiment {experiment}" if run else "no run"
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
    booked = _api(ctx).create("run_again", path={"id": run})
    new_run = booked.get("run") or {}
    if as_json:
        _print_json(booked)
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
        _print_json(answer)
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


@app.command()
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
    api = _api(ctx)
    if reservation is None:
        reservation = api.call("run", path={"id": run})["reservation"]
    cancelled = api.call(
        "reservation_cancel",
        path={"id": reservation},
        params={"reason": reason} if reason else None,
    )
    if as_json:
        _print_json(cancelled)
    else:
        out.print(f"Reservation {cancelled['id']} is {cancelled['state']}.")


@app.command()
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
    attached = _api(ctx).create(
        "reservation_attach", {"experiment": experiment}, path={"id": reservation}
    )
    run = attached["run"]
    if as_json:
        _print_json(attached)
    elif quiet:
        out.print(run["id"])
    else:
        out.print(
            f"Reservation {attached['id']} runs experiment {experiment} as run {run['id']}: "
            f"{', '.join(attached['resources'])}, {times.local(attached['start_at'])} to "
            f"{times.local(attached['end_at'])}."
        )


# --- runs -----------------------------------------------------------------------------------


@app.command()
@reports_errors
def runs(
    ctx: typer.Context,
    state: Annotated[
        str | None, typer.Option(metavar="STATE", help="Only runs in this state.")
    ] = None,
    limit: Annotated[
        int, typer.Option(metavar="N", min=1, help="At most this many, latest first.")
    ] = 50,
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Your runs, latest first."""
    listed = list(_api(ctx).pages("runs", params={"state": state} if state else None, limit=limit))
    if as_json:
        _print_json(listed)
        return
    if quiet:
        for r in listed:
            out.print(r["id"])
        return
    table = Table("run", "title", "robot", "state", "start", "samples", box=None)
    for r in listed:
        table.add_row(
            str(r["id"]),
            r["title"],
            r["resource"],
            r["state"],
            times.local(r["start_at"]),
            str(r["sample_count"]),
        )
    out.print(table)


def _program_s(run: dict[str, Any]) -> float:
    return float(sum(s["duration_s"] for s in run["segments"]))


def _polls(api: Api, run_id: int, interval_s: float) -> Iterator[dict[str, Any]]:
    while True:
        yield api.call("run", path={"id": run_id})
        time.sleep(interval_s)


def _progress_of(run: dict[str, Any]) -> tuple[float, str]:
    """How far into its program a run is (seconds), and a word on it."""
    state, samples = run["state"], run["sample_count"]
    elapsed_s = (times.now() - times.parse_api(run["start_at"])).total_seconds()
    if state in ("scheduled", "staged"):
        return 0.0, f"{state}, starts in {times.seconds(max(0, round(-elapsed_s)))}"
    if state == "running":
        return min(max(0.0, elapsed_s), _program_s(run)), f"running, {samples} samples"
    return _program_s(run), f"{state}, {samples} samples"


@app.command()
@reports_errors
def watch(
    ctx: typer.Context,
    run: Annotated[int, typer.Argument(metavar="RUN", help="The run to follow.")],
    interval: Annotated[
        float, typer.Option(metavar="SECONDS", min=0.2, help="Seconds between looks.")
    ] = 1.0,
    as_json: JsonOption = False,
) -> None:
    """Follow a run's state with a progress bar until it ends (exit 1 unless completed)."""
    api = _api(ctx)
    progress = Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TextColumn("{task.fields[info]}"),
        console=err,
        disable=as_json,
    )
    current: dict[str, Any] = {}
    last_state = None
    with progress:
        task = None
        for current in _polls(api, run, interval):
            if task is None:
                task = progress.add_task(f"run {run}", total=_program_s(current) or 1, info="")
            if current["state"] != last_state and not as_json:
                progress.console.print(f"run {run}: {current['state']}", markup=False)
            last_state = current["state"]
            done, info = _progress_of(current)
            progress.update(task, completed=done, info=info)
            if current["state"] in RUN_END_STATES:
                break
    if as_json:
        _print_json(current)
    else:
        reason = f" ({current['reason']})" if current.get("reason") else ""
        out.print(
            f"Run {run} {current['state']}{reason}: {current['sample_count']} samples.",
            markup=False,
        )
    raise typer.Exit(OK if current["state"] == "completed" else RUN_NOT_COMPLETED)


@app.command()
@reports_errors
def download(
    ctx: typer.Context,
    run: Annotated[int, typer.Argument(metavar="RUN", help="The run whose samples to download.")],
    format: Annotated[
        str, typer.Option("--format", "-f", metavar="FORMAT", help="csv or json.")
    ] = "csv",
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            metavar="FILE",
            help="File to write; `-` for stdout. Default: amazing-run-RUN.csv (or .json) here.",
        ),
    ] = None,
    as_json: JsonOption = False,
) -> None:
    """Download every sample of a run, streamed, with a progress bar; `--format zip` is the
    self-describing package (samples, metadata, a README of every column)."""
    if format not in ("csv", "json", "zip"):
        raise bad_input(f"--format {format!r}: give csv, json or zip")
    api = _api(ctx)
    details = api.call("run", path={"id": run})
    target = output or Path(f"amazing-run-{run}.{format}")
    to_stdout = str(target) == "-"
    if format == "zip" and to_stdout:
        raise bad_input("--format zip: give a file with --output (a zip is not for a terminal)")
    operation = {"csv": "samples_csv", "json": "samples_json", "zip": "run_package"}[format]
    response = api.stream(operation, path={"id": run})
    total = details["sample_count"] if format == "csv" else None
    newlines = 0
    size = 0
    columns = (
        [
            TextColumn("{task.description}"),
            BarColumn(),
            TaskProgressColumn(),
            TextColumn("{task.completed:.0f}/{task.total:.0f} samples"),
        ]
        if total is not None
        else [
            SpinnerColumn(),
            TextColumn("{task.description}"),
            DownloadColumn(),
            TransferSpeedColumn(),
        ]
    )
    partial = target.with_name(target.name + ".part") if not to_stdout else None
    try:
        with Progress(*columns, TimeElapsedColumn(), console=err, disable=as_json) as progress:
            task = progress.add_task(f"run {run} {format}", total=total)
            sink = sys.stdout.buffer if to_stdout else open(partial, "wb")  # type: ignore[arg-type]  # noqa: SIM115
            try:
                for chunk in response.iter_content(chunk_size=64 * 1024):
                    sink.write(chunk)
                    size += len(chunk)
                    newlines += chunk.count(b"\n")
                    done = max(0, newlines - 1) if total is not None else size
                    progress.update(task, completed=done)
            finally:
                if not to_stdout:
                    sink.close()
    except OSError as exc:
        raise bad_input(f"cannot write {target}: {exc}") from exc
    except Exception as exc:
        if partial is not None:
            partial.unlink(missing_ok=True)
        if isinstance(exc, CliError):
            raise
        raise CliError(
            f"the download of run {run} broke off: {exc}", exit_code=UNAVAILABLE
        ) from exc
    finally:
        response.close()
    if partial is not None:
        partial.replace(target)
    if format == "zip":
        # Checked as a reader would: a format it knows, the columns, every sample.
        samples: int | None = read_package(target).rows
    elif format == "csv":
        samples = max(0, newlines - 1)
    else:
        samples = len(json.loads(target.read_bytes())["samples"]) if not to_stdout else None
    if (
        details["state"] in RUN_END_STATES
        and samples is not None
        and samples != details["sample_count"]
    ):
        raise CliError(
            f"run {run}: downloaded {samples} samples, the portal holds "
            f"{details['sample_count']}; download it again",
            exit_code=UNAVAILABLE,
        )
    summary = {"run": run, "format": format, "path": str(target), "samples": samples, "bytes": size}
    if as_json:
        (err if to_stdout else out).print_json(json.dumps(summary))
    else:
        (err if to_stdout else out).print(
            f"Wrote {target}: {samples if samples is not None else '?'} samples, {size} bytes.",
            markup=False,
        )


def main() -> int:
    try:
        app()
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    return OK
