"""Runs and reservations in the Django admin: read-only, changed only by named actions.

Each action calls the same service the rest of the system uses (``run_transition`` through
``run_give_up``; ``reservation_cancel`` and ``reservation_decide``, which change a reservation
and its run together), so the transition table, the booking rules and the audit log apply.
Reservations are here, not in ``bookings/admin.py``, because their actions change their runs:
nothing in the admin adds, edits or deletes a reservation row (a deleted one would take its
run with it, behind its agent's back).
"""

from __future__ import annotations

from collections.abc import Callable

from django import forms
from django.contrib import admin, messages
from django.contrib.admin.helpers import ActionForm
from django.db.models import QuerySet
from django.http import HttpRequest

from bookings.choices import Channel
from bookings.models import Reservation, ReservationItem
from core.errors import DomainError
from portal.runs.models import Run, RunEvent
from portal.runs.services.reservations import reservation_cancel, reservation_decide
from portal.runs.services.transitions import run_give_up


class ReasonActionForm(ActionForm):
    reason = forms.CharField(required=False, label="Reason", max_length=500)


def _action_reason(admin_view: admin.ModelAdmin, request: HttpRequest) -> str | None:
    reason = request.POST.get("reason", "").strip()
    if not reason:
        admin_view.message_user(request, "Give a reason for the action.", messages.ERROR)
        return None
    return reason


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
        return _action_reason(self, request)

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
                reservation_cancel(
                    reservation=run.reservation,
                    by=request.user,  # type: ignore[arg-type]
                    reason=reason,
                    via=Channel.ADMIN,
                )
            except DomainError as exc:
                self.message_user(request, f"Run {run.pk}: {exc.message}", messages.ERROR)
            else:
                self.message_user(request, f"Run {run.pk}: booking cancelled.", messages.SUCCESS)


class ReservationItemInline(admin.TabularInline):
    model = ReservationItem
    extra = 0
    readonly_fields = ["resource", "start_at", "end_at", "active"]
    can_delete = False

    def has_add_permission(self, request: HttpRequest, obj: object = None) -> bool:
        return False


@admin.register(Reservation)
class ReservationAdmin(admin.ModelAdmin):
    """Read-only rows; approve, reject and cancel through the booking service of runs."""

    list_display = ["id", "owner", "start_at", "end_at", "state", "title", "conflict"]
    list_filter = ["state", "items__resource"]
    date_hierarchy = "start_at"
    inlines = [ReservationItemInline]
    readonly_fields = [f.name for f in Reservation._meta.fields]
    action_form = ReasonActionForm
    actions = ["approve", "reject", "cancel"]

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False  # booked through the pages, the API or the lease API

    def has_delete_permission(self, request: HttpRequest, obj: object = None) -> bool:
        return False  # cancelled through ``reservation_cancel``; the row and its run are kept

    def _each(
        self,
        request: HttpRequest,
        queryset: QuerySet[Reservation],
        act: Callable[[Reservation], object],
        done: str,
    ) -> None:
        """``act`` on each reservation through the runs' booking service; a refusal is shown
        for that reservation and the others go on."""
        for reservation in queryset:
            try:
                act(reservation)
            except DomainError as exc:
                self.message_user(
                    request, f"Reservation {reservation.pk}: {exc.message}", messages.ERROR
                )
            else:
                self.message_user(
                    request, f"Reservation {reservation.pk} {done}.", messages.SUCCESS
                )

    def _decide(
        self, request: HttpRequest, queryset: QuerySet[Reservation], *, approve: bool
    ) -> None:
        reason = request.POST.get("reason", "").strip()
        self._each(
            request,
            queryset,
            lambda reservation: reservation_decide(
                reservation=reservation,
                by=request.user,  # type: ignore[arg-type]
                approve=approve,
                reason=reason,
                via=Channel.ADMIN,
            ),
            "approved" if approve else "rejected",
        )

    @admin.action(description="Approve (requested bookings)")
    def approve(self, request: HttpRequest, queryset: QuerySet[Reservation]) -> None:
        self._decide(request, queryset, approve=True)

    @admin.action(description="Reject (requested bookings; a reason; the run is withdrawn)")
    def reject(self, request: HttpRequest, queryset: QuerySet[Reservation]) -> None:
        self._decide(request, queryset, approve=False)

    @admin.action(description="Cancel (a reason; a staged or running run is withdrawn)")
    def cancel(self, request: HttpRequest, queryset: QuerySet[Reservation]) -> None:
        reason = _action_reason(self, request)
        if reason is None:
            return
        self._each(
            request,
            queryset,
            lambda reservation: reservation_cancel(
                reservation=reservation,
                by=request.user,  # type: ignore[arg-type]
                reason=reason,
                via=Channel.ADMIN,
            ),
            "cancelled",
        )
