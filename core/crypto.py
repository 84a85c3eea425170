"""Secrets the portal must read back, encrypted at rest under a key of the deployment.

Fernet (``cryptography``) under a key derived from ``DJANGO_SECRET_KEY`` by HKDF, bound to one
purpose by its ``info``: the same secret key derives a different key for each purpose. The
secret key comes from the environment, is required in production and is a per-checkout file
under the data folder in development (``portal/settings.py``); ``DJANGO_SECRET_KEY_FALLBACKS``
still decrypts what was stored under a previous key, while the first key encrypts.
"""

from __future__ import annotations

import base64

from cryptography.fernet import Fernet, InvalidToken, MultiFernet
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.kdf.hkdf import HKDF
from django.conf import settings


class Unreadable(Exception):
    """A stored secret cannot be decrypted: the secret key changed without its fallback."""


def _fernet_key(secret: str, purpose: bytes) -> bytes:
    key = HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=purpose).derive(
        secret.encode("utf-8")
    )
    return base64.urlsafe_b64encode(key)


def cipher(purpose: bytes) -> MultiFernet:
    """The cipher of ``purpose``: the current secret key encrypts, every key decrypts."""
    secrets_in_use = [settings.SECRET_KEY, *getattr(settings, "SECRET_KEY_FALLBACKS", [])]
    return MultiFernet([Fernet(_fernet_key(secret, purpose)) for secret in secrets_in_use])


def encrypt(text: str, *, purpose: bytes) -> str:
    return cipher(purpose).encrypt(text.encode("utf-8")).decode("ascii")


def decrypt(ciphertext: str, *, purpose: bytes) -> str:
    try:
        return cipher(purpose).decrypt(ciphertext.encode("ascii")).decode("utf-8")
    except InvalidToken:
        raise Unreadable(
            "a stored secret cannot be decrypted: DJANGO_SECRET_KEY changed (keep the old one "
            "in DJANGO_SECRET_KEY_FALLBACKS) or the row was altered"
        ) from None
