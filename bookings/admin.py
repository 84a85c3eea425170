"""The Django admin for bookings' own models. Reservations are in the runs layer's admin
(``portal/runs/admin.py``): a reservation may hold a run, and its actions change both."""

from django import forms
from django.contrib import admin
from django.http import HttpRequest

from bookings.models import (
    Blackout,
    QuotaPolicy,
    Resource,
    ResourceGroup,
    SchedulerLease,
    SchedulerLink,
)
from bookings.rules import resource_limit_problem


@admin.register(ResourceGroup)
class ResourceGroupAdmin(admin.ModelAdmin):
    list_display = ["name", "description"]


class ResourceForm(forms.ModelForm):
    class Meta:
        model = Resource
        fields = [
            "name",
            "kind",
            "description",
            "groups",
            "agent_url",
            "agent_token_name",
            "max_velocity_mps",
            "max_accel_mps2",
            "enabled",
            "requires_approval",
            "hold_reason",
            "held_at",
        ]

    def clean(self) -> dict[str, object]:
        cleaned = super().clean() or {}
        # The instance carries the agent's recorded limits; the form, the new own limit.
        self.instance.max_velocity_mps = cleaned.get("max_velocity_mps")
        why = resource_limit_problem(self.instance)
        if why is not None:
            self.add_error("max_velocity_mps", why)
        return cleaned


@admin.register(Resource)
class ResourceAdmin(admin.ModelAdmin):
    form = ResourceForm
    list_display = [
        "name",
        "kind",
        "enabled",
        "requires_approval",
        "agent_url",
        "max_velocity_mps",
        "agent_max_velocity_mps",
        "agent_limit_warning",
    ]
    list_filter = ["kind", "enabled", "requires_approval", "groups"]
    filter_horizontal = ["groups"]
    readonly_fields = [
        "agent_limit_warning",
        "agent_max_velocity_mps",
        "agent_max_accel_mps2",
        "robot_hard_max_velocity_mps",
        "agent_limits_at",
    ]

    @admin.display(description="Limits")
    def agent_limit_warning(self, obj: Resource) -> str:
        if obj.agent_is_stricter:
            return (
                f"Its base station allows only {obj.agent_max_velocity_mps:g} m/s, below this "
                f"resource's {obj.max_velocity_mps:g} m/s: programs are checked against "
                f"{obj.agent_max_velocity_mps:g} m/s. Lower max velocity to match."
            )
        return ""


@admin.register(Blackout)
class BlackoutAdmin(admin.ModelAdmin):
    list_display = ["reason", "start_at", "end_at", "all_resources", "created_by"]
    readonly_fields = ["created_by", "created_at"]


@admin.register(QuotaPolicy)
class QuotaPolicyAdmin(admin.ModelAdmin):
    list_display = [
        "name",
        "user",
        "group",
        "resource",
        "resource_group",
        "period",
        "max_hours",
        "max_count",
        "active",
    ]
    list_filter = ["active", "period"]


class ReadOnlyAdmin(admin.ModelAdmin):
    """What the scheduler sweep keeps: shown, never edited by hand."""

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(self, request: HttpRequest, obj: object = None) -> bool:
        return False

    def has_delete_permission(self, request: HttpRequest, obj: object = None) -> bool:
        return False


@admin.register(SchedulerLease)
class SchedulerLeaseAdmin(ReadOnlyAdmin):
    list_display = ["name", "account_name", "status", "holds", "start_at", "end_at", "reservation"]
    list_filter = ["holds", "status"]
    search_fields = ["name", "uuid", "account_name"]


@admin.register(SchedulerLink)
class SchedulerLinkAdmin(ReadOnlyAdmin):
    list_display = ["last_success_at", "last_error_at", "leases_seen", "orphans_cancelled"]
