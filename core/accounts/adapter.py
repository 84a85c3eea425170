from __future__ import annotations

from allauth.account.adapter import DefaultAccountAdapter
from allauth.mfa.adapter import DefaultMFAAdapter
from django.conf import settings
from django.http import HttpRequest

from core import crypto

# Binds the derived key to this one purpose (core/crypto.py).
MFA_SECRETS_PURPOSE = b"amazing mfa secrets v1"


class AccountAdapter(DefaultAccountAdapter):
    """Self sign-up is off unless ``ACCOUNT_ALLOW_SIGNUP``: testbed admins create accounts."""

    def is_open_for_signup(self, request: HttpRequest) -> bool:
        return bool(getattr(settings, "ACCOUNT_ALLOW_SIGNUP", False))


class MfaAdapter(DefaultMFAAdapter):
    """TOTP secrets and recovery-code seeds stored encrypted (Fernet under a key derived from
    ``DJANGO_SECRET_KEY``): a database dump holds no second factor."""

    def encrypt(self, text: str) -> str:
        return crypto.encrypt(text, purpose=MFA_SECRETS_PURPOSE)

    def decrypt(self, encrypted_text: str) -> str:
        return crypto.decrypt(encrypted_text, purpose=MFA_SECRETS_PURPOSE)
