from django.contrib import admin

from portal.queue.models import QueueRequest


@admin.register(QueueRequest)
class QueueRequestAdmin(admin.ModelAdmin):
    """Read only: a request changes through the queue's services (the API), which audit."""

    list_display = ["id", "owner", "robot", "state", "priority", "earliest_at", "latest_end_at"]
    list_filter = ["state"]

    def has_add_permission(self, request: object, obj: object = None) -> bool:
        return False

    def has_change_permission(self, request: object, obj: object = None) -> bool:
        return False

    def has_delete_permission(self, request: object, obj: object = None) -> bool:
        return False
