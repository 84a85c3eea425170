from django.apps import AppConfig
from django.db.models.signals import post_delete, post_save

from core.accounts.token_cache import token_deleted, user_saved


class AccountsConfig(AppConfig):
    name = "core.accounts"
    label = "accounts"
    verbose_name = "Accounts"

    def ready(self) -> None:
        # The API token cache forgets a user whose token or account changes.
        post_delete.connect(token_deleted, sender="authtoken.Token", dispatch_uid="tokens:deleted")
        post_save.connect(user_saved, sender="accounts.User", dispatch_uid="tokens:user-saved")
