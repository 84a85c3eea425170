from importlib import import_module

from django.apps import AppConfig


class WebhooksConfig(AppConfig):
    name = "core.webhooks"
    label = "webhooks"
    verbose_name = "Webhooks"

    def ready(self) -> None:
        # Its reaction to events registers itself (core.events.dispatch).
        import_module("core.webhooks.handlers")
