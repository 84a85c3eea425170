from importlib import import_module

from django.apps import AppConfig


class QueueConfig(AppConfig):
    name = "portal.queue"
    label = "queue"
    verbose_name = "Queue (as soon as possible)"

    def ready(self) -> None:
        import_module("portal.queue.handlers")
