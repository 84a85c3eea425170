"""Let a staff account set up its first second factor (the first admin, or a lost phone)."""

from __future__ import annotations

from typing import Any

from django.core.management.base import BaseCommand, CommandError, CommandParser

from core.accounts.models import User
from core.audit.services import audit_record


class Command(BaseCommand):
    help = "Let a staff account set up its first second factor at its next sign-in."

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("username")

    def handle(self, *args: Any, username: str, **options: Any) -> None:
        user = User.objects.filter(username=username).first()
        if user is None:
            raise CommandError(f"No account {username!r}.")
        user.mfa_enrolment_allowed = True
        user.save(update_fields=["mfa_enrolment_allowed"])
        audit_record(actor=None, action="account.mfa_enrolment_allowed", target=user, via="cli")
        self.stdout.write(f"{username} may set up its second factor at its next sign-in.")
