"""The stand-in broker over HTTP: a Flask app that answers the broker's ``/resources`` calls
(and, with ``--test-control``, the ``/_standin/`` ones) in omf_sfa's words and envelope."""

from __future__ import annotations

import hmac
import json
import logging
import math
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import unquote

from flask import Flask, Response, g, request
from werkzeug.exceptions import HTTPException

from bookings.scheduler.standin.broker import (
    Broker,
    BrokerError,
    Clock,
    Faults,
    _object,
    _time_s,
    _wire,
)
from bookings.scheduler.standin.config import StandinConfig
from bookings.scheduler.standin.store import LeaseStore

# Named after the package, not the module: every log line of the stand-in carries one name.
logger = logging.getLogger("bookings.scheduler.standin")

EXTENSION_KEY = "scheduler_standin"
MAX_BODY_BYTES = 64 * 1024
MAX_DELAY_S = 60.0


def create_app(config: StandinConfig, *, clock: Callable[[], float] = time.time) -> Flask:
    """The stand-in broker as a WSGI app. ``close_app(app)`` closes its SQLite file."""
    app = Flask(__name__)
    app.config["MAX_CONTENT_LENGTH"] = MAX_BODY_BYTES
    app.config["PROVIDE_AUTOMATIC_OPTIONS"] = False
    broker = Broker(config, LeaseStore(config.db_path), Clock(source=clock))
    app.extensions[EXTENSION_KEY] = broker
    _register_hooks(app, broker)
    _register_errors(app)
    _register_resources(app, broker)
    if config.test_control:
        _register_test_control(app, broker)
    return app


def close_app(app: Flask) -> None:
    app.extensions[EXTENSION_KEY].store.close()


def _register_hooks(app: Flask, broker: Broker) -> None:
    """Around every call: the faults, the bearer token, and one log line."""
    config = broker.config

    @app.before_request
    def _misbehave_and_authenticate() -> Response | None:
        g.started_s = time.monotonic()
        if not request.path.startswith("/resources"):
            return None
        if broker.faults.delay_s:
            time.sleep(broker.faults.delay_s)
        if broker.faults.unavailable:
            return _envelope(503, "The broker is unavailable.")
        if config.token is not None:
            offered = request.headers.get("Authorization", "")
            expected = f"Bearer {config.token}"
            if not hmac.compare_digest(offered.encode(), expected.encode()):
                return _envelope(401, "Missing or invalid credentials.")
        return None

    @app.after_request
    def _log(response: Response) -> Response:
        changes = request.method in ("POST", "PUT", "DELETE")
        if broker.faults.answer_delay_s and changes and request.path.startswith("/resources"):
            time.sleep(broker.faults.answer_delay_s)
        took_ms = (time.monotonic() - g.get("started_s", time.monotonic())) * 1000
        query = unquote(request.query_string.decode("latin-1"))
        logger.info(
            "%s %s%s %s %.1f ms",
            request.method,
            request.path,
            f"?{query}" if query else "",
            response.status_code,
            took_ms,
        )
        return response


def _register_errors(app: Flask) -> None:
    """Every error in the broker's envelope, never a traceback."""

    @app.errorhandler(BrokerError)
    def _broker_error(exc: BrokerError) -> Response:
        return _envelope(exc.code, exc.reason)

    @app.errorhandler(HTTPException)
    def _http_error(exc: HTTPException) -> Response:
        code = exc.code or 400
        reason = {404: "Invalid URL.", 405: f"Method {request.method} is not allowed here."}
        return _envelope(code, reason.get(code, exc.name))

    @app.errorhandler(Exception)
    def _unexpected(exc: Exception) -> Response:
        logger.exception("unexpected error on %s %s", request.method, request.path)
        return _envelope(500, "Internal error.")


def _register_resources(app: Flask, broker: Broker) -> None:
    """The broker's own calls: the nodes, and the leases listed, made, moved and cancelled."""

    @app.get("/resources/nodes", strict_slashes=False)
    def nodes() -> Response:
        return _answer(broker.nodes(request.args))

    @app.get("/resources/leases", strict_slashes=False)
    def leases() -> Response:
        return _answer(broker.leases(request.args))

    @app.post("/resources/leases", strict_slashes=False)
    def lease_create() -> Response:
        return _answer(broker.create(_body()))

    @app.put("/resources/leases", strict_slashes=False)
    def lease_move() -> Response:
        return _answer(broker.move(_body()))

    @app.delete("/resources/leases", strict_slashes=False)
    def lease_cancel() -> Response:
        return _answer(broker.cancel(_body()))


def _register_test_control(app: Flask, broker: Broker) -> None:
    @app.post("/_standin/reset")
    def reset() -> Response:
        broker.store.clear()
        broker.faults = Faults()
        broker.clock.offset_s = 0.0
        return _plain({"reset": True})

    @app.route("/_standin/clock", methods=["GET", "POST"])
    def clock() -> Response:
        if request.method == "POST":
            descr = _object(_body())
            if "now" in descr:
                target_s = _time_s("now", descr["now"])
                broker.clock.offset_s = target_s - broker.clock.source()
            elif "offset_s" in descr:
                broker.clock.offset_s = _number("offset_s", descr["offset_s"], limit=1e10)
            else:
                raise BrokerError(400, "Give now (a time) or offset_s (seconds).")
        now_s = broker.clock.now_s()
        return _plain({"now": _wire(math.floor(now_s)), "offset_s": broker.clock.offset_s})

    @app.route("/_standin/faults", methods=["GET", "POST"])
    def faults() -> Response:
        if request.method == "POST":
            descr = _object(_body())
            delay_s = broker.faults.delay_s
            unavailable = broker.faults.unavailable
            answer_delay_s = broker.faults.answer_delay_s
            if "delay_s" in descr:
                delay_s = _number("delay_s", descr["delay_s"], limit=MAX_DELAY_S)
                if delay_s < 0:
                    raise BrokerError(400, "delay_s must not be negative.")
            if "answer_delay_s" in descr:
                answer_delay_s = _number(
                    "answer_delay_s", descr["answer_delay_s"], limit=MAX_DELAY_S
                )
                if answer_delay_s < 0:
                    raise BrokerError(400, "answer_delay_s must not be negative.")
            if "unavailable" in descr:
                if not isinstance(descr["unavailable"], bool):
                    raise BrokerError(400, "unavailable must be true or false.")
                unavailable = descr["unavailable"]
            broker.faults = Faults(
                delay_s=delay_s, unavailable=unavailable, answer_delay_s=answer_delay_s
            )
        return _plain(
            {
                "delay_s": broker.faults.delay_s,
                "unavailable": broker.faults.unavailable,
                "answer_delay_s": broker.faults.answer_delay_s,
            }
        )

    @app.post("/_standin/leases")
    def seed() -> Response:
        return _answer(broker.seed(_body()))


def _number(label: str, value: object, *, limit: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BrokerError(400, f"{label} must be a number.")
    number = float(value)
    if not math.isfinite(number) or abs(number) > limit:
        raise BrokerError(400, f"{label} must be a number within ±{limit:g}.")
    return number


def _body() -> object:
    raw = request.get_data(cache=False)
    if not raw.strip():
        raise BrokerError(400, "Message body is empty")
    try:
        return json.loads(raw)
    except (ValueError, RecursionError) as exc:
        raise BrokerError(400, f"Problems parsing body ({str(exc)[:120]})") from None


def _answer(inner: dict[str, Any]) -> Response:
    inner = {**inner, "about": request.path}
    return _plain({"resource_response": inner})


def _plain(payload: dict[str, Any]) -> Response:
    return Response(json.dumps(payload, indent=2) + "\n", mimetype="application/json")


def _envelope(code: int, reason: str) -> Response:
    # omf_sfa labels its error bodies text/json; clients must not depend on the label.
    body = json.dumps({"exception": {"code": code, "reason": reason}}, indent=2) + "\n"
    return Response(body, status=code, content_type="text/json")
