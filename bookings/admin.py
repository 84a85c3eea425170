from django.contrib import admin

from bookings.models import Reservation, Resource


@admin.register(Resource)
class ResourceAdmin(admin.ModelAdmin):
    list_display = ["name", "kind", "enabled", "agent_url", "max_velocity_mps"]
    list_filter = ["kind", "enabled"]


@admin.register(Reservation)
class ReservationAdmin(admin.ModelAdmin):
    list_display = ["id", "resource", "owner", "start_at", "end_at", "state"]
    list_filter = ["state", "resource"]
    date_hierarchy = "start_at"
