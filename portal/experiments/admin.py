from django.contrib import admin

from portal.experiments.models import Experiment, Run, RunEvent


@admin.register(Experiment)
class ExperimentAdmin(admin.ModelAdmin):
    list_display = ["title", "owner", "created_at"]


class RunEventInline(admin.TabularInline):
    model = RunEvent
    extra = 0
    can_delete = False
    readonly_fields = ["from_state", "to_state", "at", "reason"]


@admin.register(Run)
class RunAdmin(admin.ModelAdmin):
    list_display = ["id", "title", "state", "start_at", "end_at", "last_seq"]
    list_filter = ["state"]
    inlines = [RunEventInline]
