"""The book page on a phone: a robot and a fixed node ticked and booked together from an
experiment's "Book", landing on the run's page with its countdown; nothing wider than the
screen on the way."""

from __future__ import annotations

import re
from datetime import timedelta

import pytest
from django.conf import settings
from django.utils import timezone
from playwright.sync_api import expect

from bookings.models import Reservation
from tests.browser.conftest import login
from tests.factories import (
    ExperimentFactory,
    FixedResourceFactory,
    MobileResourceFactory,
    UserFactory,
)

pytestmark = [pytest.mark.browser, pytest.mark.django_db(transaction=True)]


def test_a_robot_and_a_node_are_booked_together_on_a_phone(browser, live_server):
    owner = UserFactory(username="mia")
    MobileResourceFactory(name="mobile-1")
    FixedResourceFactory(name="node-01")
    FixedResourceFactory(name="node-02")
    experiment = ExperimentFactory(owner=owner, title="phone lap")
    context = browser.new_context(
        viewport={"width": 375, "height": 800}, timezone_id=settings.TIME_ZONE
    )
    page = context.new_page()
    login(page, live_server.url, "mia", "correct horse battery")
    page.goto(f"{live_server.url}/experiments/{experiment.pk}/")
    page.locator("#book-experiment").click()
    expect(page.get_by_label("mobile-1 (robot)")).to_be_checked()
    page.get_by_label("node-02").check()
    start = (timezone.now() + timedelta(days=1)).astimezone(timezone.get_current_timezone())
    page.get_by_label("Start").fill(start.strftime("%Y-%m-%dT10:00"))
    page.get_by_label("End").fill(start.strftime("%Y-%m-%dT10:30"))
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    page.get_by_role("button", name="Book", exact=True).click()
    expect(page).to_have_url(re.compile(r"/runs/\d+/$"))
    reservation = Reservation.objects.get()
    assert sorted(i.resource.name for i in reservation.items.all()) == ["mobile-1", "node-02"]
    assert page.url.endswith(f"/runs/{reservation.run.pk}/")
    expect(page.locator("#run-countdown")).to_contain_text("Starts at 10:00:00")
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1")
    context.close()
