"""The OpenAPI description holds against the admin's token: the operations whose answer or
permission is staff's own (``tests/api/test_contract.py`` holds the rest, and says how)."""

from __future__ import annotations

import pytest

from tests.api.test_contract import TEST_TIMEOUT_S, schemathesis_finds_nothing

pytestmark = [pytest.mark.integration, pytest.mark.long, pytest.mark.django_db(transaction=True)]


@pytest.mark.timeout(TEST_TIMEOUT_S)
def test_schemathesis_finds_nothing_against_a_live_portal_as_an_admin(tmp_path):
    schemathesis_finds_nothing("admin", tmp_path)
