"""``manage.py api_token create USERNAME [--name NAME] [--expires-in-days N]``: a new API
token for a user, printed once (only its digest is kept). For operators and set-up scripts;
users make their own on the "API tokens" page or with ``amazing login``.
"""

from __future__ import annotations

from typing import Any

from django.core.management.base import BaseCommand, CommandError, CommandParser

from core.accounts.models import User
from core.accounts.services import api_token_create
from core.errors import DomainError


class Command(BaseCommand):
    help = "Make an API token for a user and print it (it is shown this once)."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("action", choices=["create"])
        parser.add_argument("username")
        parser.add_argument("--name", default="made by manage.py api_token")
        parser.add_argument("--expires-in-days", type=int, default=None)

    def handle(self, *args: Any, **options: Any) -> None:
        user = User.objects.filter(username=options["username"]).first()
        if user is None:
            raise CommandError(f"no user {options['username']!r}")
        try:
            _, token = api_token_create(
                user=user, name=options["name"], expires_in_days=options["expires_in_days"]
            )
        except DomainError as exc:
            raise CommandError(exc.message) from exc
        self.stdout.write(token)
