from importlib import import_module

from django.apps import AppConfig
from django.db.models.signals import post_delete, post_save

from core.accounts.token_cache import authenticator_changed, token_deleted, user_saved


class AccountsConfig(AppConfig):
    name = "core.accounts"
    label = "accounts"
    verbose_name = "Accounts"

    def ready(self) -> None:
        # The API token cache forgets a token that goes, and every token of a user whose
        # account or MFA changes (core/accounts/token_cache.py).
        post_delete.connect(
            token_deleted, sender="accounts.ApiToken", dispatch_uid="tokens:deleted"
        )
        post_save.connect(user_saved, sender="accounts.User", dispatch_uid="tokens:user-saved")
        # MFA on ends other sessions, MFA off revokes staff tokens (core/accounts/receivers.py).
        import_module("core.accounts.receivers").connect()
        for signal in (post_save, post_delete):
            signal.connect(
                authenticator_changed, sender="mfa.Authenticator", dispatch_uid="tokens:mfa"
            )
