"""Who may call an API action, as far as accounts decide it."""

from __future__ import annotations

from typing import Any

from rest_framework.permissions import BasePermission
from rest_framework.request import Request

from core.accounts.staff import (
    ADMINS_ONLY,
    SIGN_IN_WITH_SECOND_FACTOR,
    has_staff_role,
    staff_verified,
)


class StaffVerified(BasePermission):
    """A staff-only API action: staff whose session passed its second factor, or a staff
    token minted from such a session (``core.accounts.staff.staff_verified``)."""

    message = ADMINS_ONLY

    def has_permission(self, request: Request, view: Any) -> bool:
        if staff_verified(request):
            return True
        if has_staff_role(request.user):
            self.message = SIGN_IN_WITH_SECOND_FACTOR
        return False
