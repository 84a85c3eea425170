"""Who may call an API action, as far as accounts decide it."""

from __future__ import annotations

from typing import Any

from rest_framework.permissions import IsAdminUser
from rest_framework.request import Request

from core.accounts.mfa import mfa_enabled
from core.accounts.models import ApiToken


class StaffMfaRequired(IsAdminUser):
    """An admin-only API action: a staff user with MFA turned on."""

    message = "Staff accounts need two-factor authentication turned on for this."

    def has_permission(self, request: Request, view: Any) -> bool:
        if not super().has_permission(request, view):
            return False
        # A token of a staff account authenticates only while the account has MFA.
        return isinstance(request.auth, ApiToken) or mfa_enabled(request.user)
