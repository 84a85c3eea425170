from importlib import import_module

from django.apps import AppConfig


class RunsConfig(AppConfig):
    name = "portal.runs"
    label = "runs"
    verbose_name = "Runs: staging, collection, data and the robot console"

    def ready(self) -> None:
        # Its reactions to events register themselves (core.events.dispatch).
        import_module("portal.runs.handlers")
