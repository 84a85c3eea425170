"""Runs in the Django admin: read-only state, changed only by named actions with a reason.

Each action calls the same service the rest of the system uses (``run_transition`` through
``run_give_up``, or ``booking_cancel``), so the transition table and the audit log apply.
"""

from __future__ import annotations

from django import forms
from django.contrib import admin, messages
from django.contrib.admin.helpers import ActionForm
from django.db.models import QuerySet
from django.http import HttpRequest

from bookings.choices import Channel
from core.errors import DomainError
from portal.runs.models import Run, RunEvent
from portal.runs.services.booking import booking_cancel
from portal.runs.services.transitions import run_give_up


class ReasonActionForm(ActionForm):
    reason = forms.CharField(required=False, label="Reason", max_length=500)


class RunEventInline(admin.TabularInline):
    model = RunEvent
    extra = 0
    can_delete = False
    readonly_fields = ["from_state", "to_state", "at", "cause", "by", "reason"]

    def has_add_permission(self, request: HttpRequest, obj: object = None) -> bool:
        return False


@admin.register(Run)
class RunAdmin(admin.ModelAdmin):
    list_display = ["id", "title", "resource", "state", "start_at", "end_at", "last_seq"]
    list_filter = ["state", "resource"]
    search_fields = ["title", "reservation__owner__username"]
    readonly_fields = [
        "reservation",
        "resource",
        "experiment",
        "segments",
        "start_at",
        "end_at",
        "state",
        "reason",
        "last_seq",
        "agent_sample_count",
        "rail_length_m",
    ]
    inlines = [RunEventInline]
    action_form = ReasonActionForm
    actions = ["give_up", "cancel_booking"]

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False  # runs are made by booking

    def has_delete_permission(self, request: HttpRequest, obj: object = None) -> bool:
        return False  # a run's data and history are kept

    def _reason(self, request: HttpRequest) -> str | None:
        reason = request.POST.get("reason", "").strip()
        if not reason:
            self.message_user(request, "Give a reason for the action.", messages.ERROR)
            return None
        return reason

    @admin.action(description="Give up: mark failed (scheduled, or collecting that is stuck)")
    def give_up(self, request: HttpRequest, queryset: QuerySet[Run]) -> None:
        reason = self._reason(request)
        if reason is None:
            return
        for run in queryset:
            try:
                run_give_up(run=run, by=request.user, reason=reason)  # type: ignore[arg-type]
            except DomainError as exc:
                self.message_user(request, f"Run {run.pk}: {exc.message}", messages.ERROR)
            else:
                self.message_user(request, f"Run {run.pk} marked failed.", messages.SUCCESS)

    @admin.action(description="Cancel the booking (a staged or running run is withdrawn)")
    def cancel_booking(self, request: HttpRequest, queryset: QuerySet[Run]) -> None:
        reason = self._reason(request)
        if reason is None:
            return
        for run in queryset.select_related("reservation"):
            try:
                booking_cancel(
                    reservation=run.reservation,
                    by=request.user,  # type: ignore[arg-type]
                    reason=reason,
                    via=Channel.ADMIN,
                )
            except DomainError as exc:
                self.message_user(request, f"Run {run.pk}: {exc.message}", messages.ERROR)
            else:
                self.message_user(request, f"Run {run.pk}: booking cancelled.", messages.SUCCESS)
