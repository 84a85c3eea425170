from django.apps import AppConfig


class AccountsConfig(AppConfig):
    name = "core.accounts"
    label = "accounts"
    verbose_name = "Accounts"

    def ready(self) -> None:
        # The token cache forgets a user whose token or account changes.
        from core.accounts import tokens  # noqa: F401
