from importlib import import_module

from django.apps import AppConfig
from django.db.models.signals import post_delete, post_save

from portal.web.signals import calendar_changed, resource_saved


class WebConfig(AppConfig):
    name = "portal.web"
    label = "web"
    verbose_name = "Web pages"

    def ready(self) -> None:
        # Live pushes: of the events (portal/web/handlers.py), and of the changes that are
        # not events (portal/web/signals.py).
        import_module("portal.web.handlers")
        for signal in (post_save, post_delete):
            signal.connect(
                calendar_changed, sender="bookings.Blackout", dispatch_uid="live:blackout"
            )
        # A booking's every change is an event, but its deletion (with its owner's account).
        post_delete.connect(
            calendar_changed, sender="bookings.Reservation", dispatch_uid="live:reservation"
        )
        post_save.connect(resource_saved, sender="bookings.Resource", dispatch_uid="live:resource")
