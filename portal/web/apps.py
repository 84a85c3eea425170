from django.apps import AppConfig
from django.db.models.signals import post_delete, post_save

from portal.web.signals import CALENDAR_MODELS, calendar_changed, resource_saved


class WebConfig(AppConfig):
    name = "portal.web"
    label = "web"
    verbose_name = "Web pages"

    def ready(self) -> None:
        # Live pushes to open calendars and consoles (portal/web/signals.py).
        for label in CALENDAR_MODELS:
            for signal in (post_save, post_delete):
                signal.connect(calendar_changed, sender=label, dispatch_uid=f"live:{label}")
        post_save.connect(resource_saved, sender="bookings.Resource", dispatch_uid="live:resource")
