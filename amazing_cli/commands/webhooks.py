"""``amazing webhook …``: your webhooks (``/api/v1/webhooks/``): make one, list them, read one's
delivery log, send it a test event, resume it after a pause, delete it."""

from __future__ import annotations

from typing import Annotated, Any

import typer

from amazing_cli import times
from amazing_cli.commands._common import (
    JsonOption,
    QuietOption,
    err,
    out,
    portal_api,
    print_json,
    reports_errors,
)

WebhookId = Annotated[int, typer.Argument(metavar="ID", min=1, help="The webhook's id.")]


def _takes(webhook: dict[str, Any]) -> str:
    takes = ", ".join(webhook["types"]) if webhook["types"] else "all of yours"
    return takes + (", and staff's" if webhook["staff_events"] else "")


@reports_errors
def webhook_create(
    ctx: typer.Context,
    url: Annotated[str, typer.Argument(metavar="URL", help="https, at a public address.")],
    type: Annotated[
        list[str] | None,
        typer.Option("--type", metavar="TYPE", help="Only events of this type (repeatable)."),
    ] = None,
    description: Annotated[str, typer.Option(metavar="TEXT", help="What it is for.")] = "",
    staff_events: Annotated[
        bool,
        typer.Option(
            "--staff-events", help="Also the robots' and the scheduler link's events (staff)."
        ),
    ] = False,
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Make a webhook: your events sent to URL, signed. Prints its secret, this once."""
    made = portal_api(ctx).create(
        "webhook_create",
        {
            "url": url,
            "types": type or [],
            "description": description,
            "staff_events": staff_events,
        },
    )
    if as_json:
        print_json(made)
        return
    if quiet:
        out.print(made["id"])
    else:
        out.print(f"Made webhook {made['id']} to {made['url']}: {_takes(made)}.")
    # The secret goes to stderr with --quiet, so `id=$(amazing webhook create -q …)` keeps it
    # off the id but still in front of the person who must copy it.
    (err if quiet else out).print(
        f"Its secret (shown this once; it verifies the signatures): {made['secret']}",
        markup=False,
    )


@reports_errors
def webhook_list(ctx: typer.Context, as_json: JsonOption = False) -> None:
    """Your webhooks."""
    listed = list(portal_api(ctx).pages("webhooks"))
    if as_json:
        print_json(listed)
        return
    if not listed:
        out.print("No webhooks: `amazing webhook create URL` makes one.")
        return
    for w in listed:
        state = f"paused: {w['pause_reason']}" if w["paused"] else "active"
        about = f" ({w['description']})" if w["description"] else ""
        out.print(f"{w['id']} {w['url']}{about}: {_takes(w)}; {state}", markup=False)


@reports_errors
def webhook_log(
    ctx: typer.Context,
    webhook: WebhookId,
    limit: Annotated[
        int, typer.Option(metavar="N", min=1, help="At most this many, the newest first.")
    ] = 20,
    as_json: JsonOption = False,
) -> None:
    """A webhook's deliveries: each event's state, tries, last answer and next try."""
    deliveries = list(
        portal_api(ctx).pages("webhook_deliveries", path={"id": webhook}, limit=limit)
    )
    if as_json:
        print_json(deliveries)
        return
    if not deliveries:
        out.print(f"Nothing sent to webhook {webhook} yet: `amazing webhook test {webhook}`.")
        return
    # One line each, as `amazing events` prints: an error can be long, and a table would
    # fold the columns that say which event it was (`--json` has every field).
    for d in deliveries:
        tries = f"{d['attempts']} {'try' if d['attempts'] == 1 else 'tries'}"
        answer = str(d["last_status"]) if d["last_status"] else (d["last_error"] or "")
        last = f", last {times.local(d['last_tried_at'])}: {answer}" if d["last_tried_at"] else ""
        next_try = f", next {times.local(d['next_try_at'])}" if d["state"] == "pending" else ""
        out.print(
            f"#{d['event']} {d['type']} {d['state']}, {tries}{last}{next_try}",
            markup=False,
        )


@reports_errors
def webhook_test(
    ctx: typer.Context, webhook: WebhookId, as_json: JsonOption = False, quiet: QuietOption = False
) -> None:
    """Send a webhook a test event (`webhook.test`); `amazing webhook log` shows how it went."""
    sent = portal_api(ctx).call("webhook_test", path={"id": webhook})
    if as_json:
        print_json(sent)
    elif quiet:
        out.print(sent["event"])
    else:
        out.print(f"Test event {sent['event']} is on its way to webhook {webhook}.")


@reports_errors
def webhook_resume(ctx: typer.Context, webhook: WebhookId, as_json: JsonOption = False) -> None:
    """Send to a paused webhook again: what failed first, then what waited, in order."""
    resumed = portal_api(ctx).call("webhook_resume", path={"id": webhook})
    if as_json:
        print_json(resumed)
    else:
        out.print(f"Webhook {resumed['id']} to {resumed['url']} is active again.")


@reports_errors
def webhook_delete(
    ctx: typer.Context,
    webhook: WebhookId,
    yes: Annotated[bool, typer.Option("--yes", help="Delete without asking.")] = False,
) -> None:
    """Delete a webhook and its delivery log (your events stay)."""
    api = portal_api(ctx)
    if not yes:
        shown = api.call("webhook", path={"id": webhook})
        if not typer.confirm(f"Delete webhook {webhook} to {shown['url']}?", default=False):
            out.print("Kept it.")
            return
    api.call("webhook_delete", path={"id": webhook})
    out.print(f"Deleted webhook {webhook}.")
