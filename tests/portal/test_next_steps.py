"""Each page leads to the next step (#39, item 5): a saved experiment to trying and booking it,
a dry run to booking its program, a run not yet started to its countdown (and nothing to
repeat), a new token to copying and using it, the API's reference back to the portal and to
the tokens page it names."""

from __future__ import annotations

import re
from datetime import datetime, timedelta

import pytest
from django.utils import timezone

from core.openapi import DESCRIPTION
from portal.experiments.models import Experiment
from portal.runs.models import Run
from portal.runs.services.dry_run import dry_run_request
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, MobileResourceFactory

pytestmark = pytest.mark.django_db

PROGRAM = [{"velocity_mps": 0.4, "direction": "cw", "duration_s": 5.0}]


def test_saving_an_experiment_leads_to_trying_and_booking_it(owner, mobile, client):
    client.force_login(owner)
    answer = client.post(
        "/experiments/new/",
        {"title": "lap", "velocity_mps": ["0.4"], "direction": ["cw"], "duration_s": ["5"]},
    )
    experiment = Experiment.objects.get(owner=owner)
    assert answer.status_code == 302
    assert answer.headers["Location"] == f"/experiments/{experiment.pk}/"
    page = client.get(answer.headers["Location"]).content.decode()
    assert "saved" in page
    assert 'id="dry-run-start"' in page
    assert f'href="/book/?experiment={experiment.pk}" role="button" id="book-experiment"' in page


def test_a_dry_run_offers_to_book_its_program(owner, mobile, client):
    experiment = ExperimentFactory(owner=owner, segments=PROGRAM)
    dry_run = dry_run_request(user=owner, experiment=experiment)
    client.force_login(owner)
    page = client.get(f"/dry-runs/{dry_run.pk}/").content.decode()
    assert f'href="/book/?experiment={experiment.pk}" role="button" id="book-program"' in page
    assert "Book this program" in page


def test_a_run_counts_down_to_its_start_and_offers_to_run_again_only_once_started(owner, client):
    start = timezone.now() + timedelta(hours=1)
    run = reservation_create(
        owner=owner,
        resource=MobileResourceFactory(),
        start_at=start,
        end_at=start + timedelta(minutes=5),
        experiment=ExperimentFactory(owner=owner, segments=PROGRAM),
    ).run
    client.force_login(owner)
    page = client.get(f"/runs/{run.pk}/").content.decode()
    assert 'id="run-countdown"' in page
    # The instant in the testbed's zone, with its offset (summer or winter): the same instant.
    shown = re.search(r'id="run-countdown" data-start="([^"]+)"', page)
    assert shown is not None
    assert datetime.fromisoformat(shown.group(1)) == run.start_at
    assert 'id="run-again"' not in page

    Run.objects.filter(pk=run.pk).update(state=RunState.COMPLETED)
    page = client.get(f"/runs/{run.pk}/").content.decode()
    assert 'id="run-countdown"' not in page
    assert 'id="run-again"' in page


def test_a_new_token_comes_with_a_copy_button_and_examples_that_use_it(owner, client):
    client.force_login(owner)
    made = client.post("/account/tokens/", {"name": "laptop"}).content.decode()
    token = made.split('data-testid="new-token-value" id="new-token-value"', 1)[0]
    token = token.rsplit('value="', 1)[1].split('"', 1)[0]
    assert token.startswith("amz_")
    assert 'id="copy-token"' in made
    assert "amazing login --url http://testserver" in made
    assert f'curl -H "Authorization: Token {token}" http://testserver/api/v1/me/' in made
    # Shown once: the page read again has neither the token nor its examples.
    again = client.get("/account/tokens/").content.decode()
    assert token not in again
    assert "curl" not in again


def test_the_api_reference_leads_back_and_names_the_tokens_page(owner, client):
    client.force_login(owner)
    page = client.get("/api/docs/").content.decode()
    assert '<a href="/">← Back to the portal</a>' in page
    assert '<a href="/account/tokens/">Your API tokens</a>' in page
    assert "/account/tokens/" in DESCRIPTION
    assert "an admin creates keys" not in DESCRIPTION
