"""The agent's HTTP API: ``/healthz`` and the token-protected ``/api/v1`` blueprints."""

from __future__ import annotations

from flask import Blueprint, Flask

from basestation.api import battery, control, health, logs, metrics, rail, runs, status
from basestation.api.access import register_request_ids
from basestation.api.auth import require_bearer_token
from basestation.api.errors import register_error_handlers
from basestation.api.limits import refuse_oversized_body

API_PREFIX = "/api/v1"


def register_api(app: Flask) -> None:
    register_error_handlers(app)
    register_request_ids(app)
    # App-level, not per blueprint: it must also guard /api/v1 URLs that match no route,
    # so an unauthenticated caller cannot probe which endpoints and methods exist.
    app.before_request(require_bearer_token)
    app.before_request(refuse_oversized_body)
    app.register_blueprint(health.bp)
    api = Blueprint("api_v1", __name__, url_prefix=API_PREFIX)
    api.register_blueprint(status.bp)
    api.register_blueprint(battery.bp)
    api.register_blueprint(rail.bp)
    api.register_blueprint(runs.bp)
    api.register_blueprint(control.bp)
    api.register_blueprint(logs.bp)
    api.register_blueprint(metrics.bp)
    app.register_blueprint(api)
