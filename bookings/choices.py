from django.db import models


class ResourceKind(models.TextChoices):
    MOBILE = "mobile", "mobile node"
    FIXED = "fixed", "fixed node"


class ReservationState(models.TextChoices):
    CONFIRMED = "confirmed", "confirmed"
    CANCELLED = "cancelled", "cancelled"
    COMPLETED = "completed", "completed"


RESERVATION_ACTIVE_STATES = (ReservationState.CONFIRMED,)
