from __future__ import annotations

from django.contrib.auth.models import AbstractUser


class User(AbstractUser):
    """A person who uses the testbed.

    Experimenters book and run experiments; staff users (``is_staff``) are the testbed's
    admins. Kept as our own model from the first migration so that profile fields (group,
    affiliation, quota policy) can be added without a painful swap later.
    """

    @property
    def is_testbed_admin(self) -> bool:
        return self.is_staff or self.is_superuser
