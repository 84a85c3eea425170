from __future__ import annotations

from typing import Any

import factory

from bookings.choices import ResourceKind
from bookings.models import Resource
from core.accounts.models import User
from portal.experiments.models import Experiment


class UserFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = User
        django_get_or_create = ("username",)
        skip_postgeneration_save = True

    username = factory.Sequence(lambda n: f"user{n}")
    email = factory.LazyAttribute(lambda u: f"{u.username}@example.org")
    password = factory.PostGenerationMethodCall("set_password", "correct horse battery")

    @factory.post_generation
    def _save(self, create: bool, extracted: Any, **kwargs: Any) -> None:
        if create:
            self.save()


class MobileResourceFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Resource
        django_get_or_create = ("name",)

    name = "mobile-1"
    kind = ResourceKind.MOBILE
    agent_url = "http://127.0.0.1:1"
    max_velocity_mps = 2.0
    max_accel_mps2 = 1.0


class FixedResourceFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Resource
        django_get_or_create = ("name",)

    name = factory.Sequence(lambda n: f"node-{n + 1:02d}")
    kind = ResourceKind.FIXED


class ExperimentFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Experiment

    owner = factory.SubFactory(UserFactory)
    title = factory.Sequence(lambda n: f"experiment {n}")
    segments = factory.LazyFunction(
        lambda: [
            {"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0},
            {"velocity_mps": 0.8, "direction": "ccw", "duration_s": 3.0},
        ]
    )
