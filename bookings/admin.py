from django.contrib import admin
from django.http import HttpRequest

from bookings.models import (
    Blackout,
    QuotaPolicy,
    Reservation,
    ReservationItem,
    Resource,
    ResourceGroup,
    SchedulerLease,
    SchedulerLink,
)


@admin.register(ResourceGroup)
class ResourceGroupAdmin(admin.ModelAdmin):
    list_display = ["name", "description"]


@admin.register(Resource)
class ResourceAdmin(admin.ModelAdmin):
    list_display = ["name", "kind", "enabled", "requires_approval", "agent_url", "max_velocity_mps"]
    list_filter = ["kind", "enabled", "requires_approval", "groups"]
    filter_horizontal = ["groups"]


class ReservationItemInline(admin.TabularInline):
    model = ReservationItem
    extra = 0
    readonly_fields = ["resource", "start_at", "end_at", "active"]
    can_delete = False


@admin.register(Reservation)
class ReservationAdmin(admin.ModelAdmin):
    """Read-mostly: bookings change through the pages and API, whose services audit them."""

    list_display = ["id", "owner", "start_at", "end_at", "state", "title", "conflict"]
    list_filter = ["state", "items__resource"]
    date_hierarchy = "start_at"
    inlines = [ReservationItemInline]
    readonly_fields = [f.name for f in Reservation._meta.fields]


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
