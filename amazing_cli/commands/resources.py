"""What there is: the resources, when they are free, your quotas; and the first slot in which
several are free together, for ``amazing book``."""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Annotated

import typer
from rich.table import Table

from amazing_cli import times
from amazing_cli.api import Api
from amazing_cli.commands._common import JsonOption, out, portal_api, print_json, reports_errors
from amazing_cli.errors import NOT_FOUND, CliError

AVAILABILITY_WINDOW = timedelta(days=62) - timedelta(seconds=1)


@reports_errors
def resources(ctx: typer.Context, as_json: JsonOption = False) -> None:
    """The robots and fixed nodes."""
    listed = portal_api(ctx).call("resources")
    if as_json:
        print_json(listed)
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
    api = portal_api(ctx)
    begin = times.parse_instant(start, option="--from")
    answer = api.call(
        "availability",
        path={"name": resource},
        params={"start": times.iso(begin), "end": times.iso(begin + timedelta(days=days))},
    )
    if as_json:
        print_json(answer)
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


@reports_errors
def quota(ctx: typer.Context, as_json: JsonOption = False) -> None:
    """Your quotas and how much of them you use."""
    answer = portal_api(ctx).call("quota")
    if as_json:
        print_json(answer)
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


def first_slot(
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
