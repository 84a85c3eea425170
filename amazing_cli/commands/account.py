"""``amazing login`` and ``amazing logout``: the token the other commands use."""

from __future__ import annotations

import os
import socket
from typing import Annotated, Any

import typer

from amazing_cli import config
from amazing_cli.api import Api
from amazing_cli.commands._common import JsonOption, out, print_json, reports_errors
from amazing_cli.errors import CliError, bad_input


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
        print_json({**me, "url": current.url, "stored_in": str(path)})
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
