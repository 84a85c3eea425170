from django.contrib import admin

from bookings.models import (
    Blackout,
    QuotaPolicy,
    Reservation,
    ReservationItem,
    Resource,
    ResourceGroup,
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
