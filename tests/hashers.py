"""The password hasher of the test processes: the production algorithm with few iterations.

Django's PBKDF2 spends ~0.6 s of CPU on every password it hashes (on purpose), and the suite
makes users and signs them in by the thousand. Hashes made here are ``pbkdf2_sha256`` with
their iteration count written in them, so the real processes the integration and browser
tests start (production settings, the full count) check them as they check any other, and
upgrade them on the first sign-in as they would an old hash.
"""

from __future__ import annotations

from django.contrib.auth.hashers import PBKDF2PasswordHasher


class QuickPBKDF2PasswordHasher(PBKDF2PasswordHasher):
    iterations = 1_000
