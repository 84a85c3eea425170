"""What every command shares: the consoles, the ``--json`` and ``--quiet`` options, the API
client of the root options, and one clear line and exit code for any problem."""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console

from amazing_cli import config
from amazing_cli.api import Api
from amazing_cli.errors import CliError

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


def portal_api(ctx: typer.Context, *, authenticated: bool = True) -> Api:
    options = ctx.find_root().obj or {}
    credentials = config.load(url=options.get("url"), token=options.get("token"))
    token = config.require_token(credentials) if authenticated else credentials.token
    return Api(credentials.url, token)


def print_json(value: Any) -> None:
    out.print_json(json.dumps(value), highlight=False)
