from importlib import import_module

from django.apps import AppConfig


class BookingsConfig(AppConfig):
    name = "bookings"
    verbose_name = "Bookings"

    def ready(self) -> None:
        # Its reactions to events register themselves (core.events.dispatch).
        import_module("bookings.handlers")
