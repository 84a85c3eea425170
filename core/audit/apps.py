from importlib import import_module

from django.apps import AppConfig


class AuditConfig(AppConfig):
    name = "core.audit"
    label = "audit"
    verbose_name = "Audit log"

    def ready(self) -> None:
        # Sign-ins and their failures are audited (core/audit/signins.py); the module
        # reads models, so it is loaded now that they are.
        import_module("core.audit.signins").connect()
