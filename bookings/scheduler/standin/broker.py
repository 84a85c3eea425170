"""A stand-in for the testbed's omf_sfa broker: the lease subset of its "AM" REST API.

``python -m bookings.scheduler.standin --host 127.0.0.1 --port 8710`` serves it with
waitress. ``make run`` uses it as the embedded scheduler and the tests start it as a
separate process. It behaves as the broker does, quirks included, and each quirk that
deployments differ on is a switch (flag, or ``SCHEDULER_STANDIN_*`` variable):

- ``--conflict-as 401|409|zombie``: a clash with another lease is a 401 "Reservation for
  the resource 'X' failed…" (omf_sfa), a 409, or a 200 with a ``pending`` lease that holds
  no component (older omf_sfa; a clashing move is then omf_sfa's 400).
- ``--granularity-s N``: lease times must fall on multiples of N seconds (else 422).
- ``--empty-as-404``: an empty listing is 404 "No resources matching the request.".
- ``--token``/``--token-file``: every ``/resources`` call needs ``Authorization: Bearer``.
- ``--nodes``: the leasable nodes (default ``node-01`` … ``node-24``).
- ``--db PATH``: keep leases in a SQLite file across restarts (default: memory).
- ``--test-control``: ``/_standin/…`` endpoints that move the clock, inject faults (slow
  answers, 503) and reset everything. Never on in a deployment.

A lease made without a clash is ``accepted``; its status then follows the clock
(``active`` from its start, ``past`` from its end). Overlap is half-open and only
``accepted``/``active`` leases hold nodes. Like omf_sfa, components it does not know are
left out of the lease without a word. Every error is ``{"exception": {"code", "reason"}}``.
Docs: docs/integration.md.
"""

from __future__ import annotations

import argparse
import hmac
import json
import logging
import math
import os
import re
import signal
import sqlite3
import sys
import threading
import time
import types
import uuid as uuid_lib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any
from urllib.parse import unquote

from flask import Flask, Response, g, request
from waitress.server import create_server
from werkzeug.exceptions import HTTPException

logger = logging.getLogger("bookings.scheduler.standin")

ENV_PREFIX = "SCHEDULER_STANDIN_"
CONFLICT_MODES = ("401", "409", "zombie")
DEFAULT_NODES = tuple(f"node-{i:02d}" for i in range(1, 25))
DEFAULT_STATUSES = ("pending", "accepted", "active")
STATUSES = ("pending", "accepted", "active", "past", "cancelled")
EXTENSION_KEY = "scheduler_standin"
MAX_BODY_BYTES = 64 * 1024
MAX_NAME_CHARS = 255
MAX_DELAY_S = 60.0
WIRE_TIME_FORMAT = "%Y-%m-%dT%H:%M:%SZ"
NO_MATCH = "No resources matching the request."
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
# Times outside this range are refused rather than risk overflowing on the way back out.
_EARLIEST = datetime(1970, 1, 1, tzinfo=UTC)
_LATEST = datetime(9000, 1, 1, tzinfo=UTC)
_NODE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,62}$")


class ConfigError(ValueError):
    """A switch has a value the stand-in cannot run with."""


class BrokerError(Exception):
    """An answer in the broker's error envelope."""

    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason)
        self.code = code
        self.reason = reason


# -- configuration ------------------------------------------------------------------------


@dataclass(frozen=True)
class StandinConfig:
    conflict_as: str = "401"
    granularity_s: int = 1
    empty_as_404: bool = False
    token: str | None = field(default=None, repr=False)
    nodes: tuple[str, ...] = DEFAULT_NODES
    db_path: str = ":memory:"
    test_control: bool = False
    domain: str = "amazing"

    def __post_init__(self) -> None:
        if self.conflict_as not in CONFLICT_MODES:
            raise ConfigError(f"conflict-as must be one of {', '.join(CONFLICT_MODES)}")
        if not 1 <= self.granularity_s <= 86400:
            raise ConfigError("granularity-s must be between 1 and 86400")
        if self.token is not None and (
            not self.token or any(ch.isspace() for ch in self.token) or not self.token.isprintable()
        ):
            raise ConfigError("the token must be one printable word without spaces")
        if not self.nodes:
            raise ConfigError("the stand-in needs at least one node")
        bad = [name for name in self.nodes if not _NODE_NAME.match(name)]
        if bad:
            raise ConfigError(f"node names must be letters, digits, '.', '_' or '-': {bad}")
        if len(set(self.nodes)) != len(self.nodes):
            raise ConfigError("node names must be unique")
        if not self.db_path:
            raise ConfigError("db must be a file path or :memory:")

    @property
    def conflict_code(self) -> int:
        return 409 if self.conflict_as == "409" else 401

    @classmethod
    def from_env(cls, environ: Mapping[str, str]) -> StandinConfig:
        def get(name: str) -> str:
            return environ.get(f"{ENV_PREFIX}{name}", "").strip()

        values: dict[str, Any] = {}
        if get("CONFLICT_AS"):
            values["conflict_as"] = get("CONFLICT_AS")
        if get("GRANULARITY_S"):
            values["granularity_s"] = _int_option("GRANULARITY_S", get("GRANULARITY_S"))
        if get("EMPTY_AS_404"):
            values["empty_as_404"] = _bool_option("EMPTY_AS_404", get("EMPTY_AS_404"))
        if get("TEST_CONTROL"):
            values["test_control"] = _bool_option("TEST_CONTROL", get("TEST_CONTROL"))
        if get("NODES"):
            values["nodes"] = _node_list(get("NODES"))
        if get("DB"):
            values["db_path"] = get("DB")
        token = _token(get("TOKEN"), get("TOKEN_FILE"), label=f"{ENV_PREFIX}TOKEN")
        if token is not None:
            values["token"] = token
        return cls(**values)


def _int_option(name: str, raw: str) -> int:
    try:
        return int(raw)
    except ValueError:
        raise ConfigError(f"{name}={raw!r} is not a whole number") from None


def _bool_option(name: str, raw: str) -> bool:
    lowered = raw.lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise ConfigError(f"{name}={raw!r} must be on or off")


def _node_list(raw: str) -> tuple[str, ...]:
    return tuple(name.strip() for name in raw.split(",") if name.strip())


def _token(value: str, path: str, *, label: str) -> str | None:
    if value and path:
        raise ConfigError(f"set only one of {label} and {label}_FILE")
    if not path:
        return value or None
    try:
        return Path(path).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{label}_FILE={path} cannot be read: {exc}") from None


# -- leases and where they are kept -------------------------------------------------------


@dataclass(frozen=True)
class StoredLease:
    """``state`` is what was decided (``booked``, ``pending``, ``cancelled``, ``past``);
    the status a client sees also depends on the clock (see :meth:`status`)."""

    uuid: str
    name: str
    valid_from_s: int
    valid_until_s: int
    account: str
    state: str
    nodes: tuple[str, ...]

    def status(self, now_s: float) -> str:
        if self.state in ("cancelled", "past"):
            return self.state
        if now_s >= self.valid_until_s:
            return "past"
        if self.state == "pending":
            return "pending"
        return "active" if now_s >= self.valid_from_s else "accepted"

    def holds(self, now_s: float) -> bool:
        return bool(self.nodes) and self.status(now_s) in ("accepted", "active")


class LeaseStore:
    """The leases, in memory, written through to SQLite when a file is given.

    Callers hold :attr:`lock` around every read-check-write, so two clients racing for one
    slot cannot both win.
    """

    def __init__(self, db_path: str) -> None:
        self.lock = threading.RLock()
        self._leases: dict[str, StoredLease] = {}
        self._db: sqlite3.Connection | None = None
        if db_path != ":memory:":
            self._db = sqlite3.connect(db_path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(
                "CREATE TABLE IF NOT EXISTS lease (uuid TEXT PRIMARY KEY, name TEXT NOT NULL,"
                " valid_from_s INTEGER NOT NULL, valid_until_s INTEGER NOT NULL,"
                " account TEXT NOT NULL, state TEXT NOT NULL, nodes TEXT NOT NULL)"
            )
            for uuid, name, valid_from_s, valid_until_s, account, state, nodes in self._db.execute(
                "SELECT uuid, name, valid_from_s, valid_until_s, account, state, nodes FROM lease"
            ):
                self._leases[uuid] = StoredLease(
                    uuid=uuid,
                    name=name,
                    valid_from_s=valid_from_s,
                    valid_until_s=valid_until_s,
                    account=account,
                    state=state,
                    nodes=tuple(json.loads(nodes)),
                )

    def close(self) -> None:
        if self._db is not None:
            self._db.close()

    def all(self) -> list[StoredLease]:
        with self.lock:
            return list(self._leases.values())

    def by_uuid(self, lease_uuid: str) -> StoredLease | None:
        with self.lock:
            return self._leases.get(lease_uuid)

    def by_name(self, name: str) -> StoredLease | None:
        with self.lock:
            return next((lease for lease in self._leases.values() if lease.name == name), None)

    def save(self, lease: StoredLease) -> None:
        with self.lock:
            if self._db is not None:
                self._db.execute(
                    "INSERT OR REPLACE INTO lease VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (
                        lease.uuid,
                        lease.name,
                        lease.valid_from_s,
                        lease.valid_until_s,
                        lease.account,
                        lease.state,
                        json.dumps(list(lease.nodes)),
                    ),
                )
            self._leases[lease.uuid] = lease

    def clear(self) -> None:
        with self.lock:
            if self._db is not None:
                self._db.execute("DELETE FROM lease")
            self._leases.clear()


@dataclass
class Faults:
    """Test-only misbehaviour, switched at run time through ``/_standin/faults``."""

    delay_s: float = 0.0
    unavailable: bool = False
    # Sleep after a change (create, move, cancel), before the answer: the lease exists while
    # the caller still waits (a caller killed then leaves an orphan behind).
    answer_delay_s: float = 0.0


@dataclass
class Clock:
    """The broker's clock: the real one plus an offset that tests may move."""

    source: Callable[[], float] = time.time
    offset_s: float = 0.0

    def now_s(self) -> float:
        return self.source() + self.offset_s


# -- the broker's behaviour --------------------------------------------------------------


class Broker:
    def __init__(self, config: StandinConfig, store: LeaseStore, clock: Clock) -> None:
        self.config = config
        self.store = store
        self.clock = clock
        self.faults = Faults()
        self.node_docs = [_node_doc(name, config.domain) for name in config.nodes]

    # nodes

    def nodes(self, filters: Mapping[str, str]) -> dict[str, Any]:
        wanted = {key: filters[key] for key in ("uuid", "name", "urn") if key in filters}
        if not wanted:
            return self._listing(self.node_docs)
        for doc in self.node_docs:
            if all(doc[key] == value for key, value in wanted.items()):
                return {"resource": doc}
        raise BrokerError(404, NO_MATCH)

    # leases

    def leases(self, args: Mapping[str, str]) -> dict[str, Any]:
        raw = args.get("status", "").strip()
        statuses = [s.strip() for s in raw.split(",") if s.strip()] or list(DEFAULT_STATUSES)
        unknown = [s for s in statuses if s not in STATUSES]
        if unknown:
            raise BrokerError(400, f"Unknown lease status '{unknown[0][:40]}'.")
        now_s = self.clock.now_s()
        found = [
            lease
            for lease in self.store.all()
            if lease.status(now_s) in statuses
            and ("uuid" not in args or lease.uuid == args["uuid"])
            and ("name" not in args or lease.name == args["name"])
        ]
        found.sort(key=lambda lease: (lease.valid_from_s, lease.uuid))
        return self._listing([self.lease_doc(lease, now_s) for lease in found])

    def create(self, body: object) -> dict[str, Any]:
        descr = _object(body)
        name = descr.get("name")
        if name is not None and (not isinstance(name, str) or not 0 < len(name) <= MAX_NAME_CHARS):
            raise BrokerError(400, f"Attribute name must be a string of 1 to {MAX_NAME_CHARS}.")
        account = _account(descr)
        components = _present(descr, "components") or _present(descr, "components_attributes")
        if not isinstance(components, list) or not components:
            raise BrokerError(400, "Attribute components is mandatory.")
        if "valid_from" not in descr or "valid_until" not in descr:
            raise BrokerError(400, "Attributes valid_from and valid_until are mandatory.")
        valid_from_s = _time_s("valid_from", descr["valid_from"])
        valid_until_s = _time_s("valid_until", descr["valid_until"])
        self._check_window(valid_from_s, valid_until_s)
        nodes = self._resolve(components)
        with self.store.lock:
            now_s = self.clock.now_s()
            clashes = self._clashes(nodes, valid_from_s, valid_until_s, now_s, exclude=None)
            lease_uuid = str(uuid_lib.uuid4())
            lease = StoredLease(
                uuid=lease_uuid,
                name=name if isinstance(name, str) else lease_uuid,
                valid_from_s=valid_from_s,
                valid_until_s=valid_until_s,
                account=account,
                state="booked" if nodes else "pending",
                nodes=nodes,
            )
            if clashes:
                if self.config.conflict_as != "zombie":
                    raise BrokerError(self.config.conflict_code, self._clash_reason(clashes))
                # Older omf_sfa: the lease is made anyway, pending, holding nothing.
                lease = replace(lease, state="pending", nodes=())
            self.store.save(lease)
            return {"resource": self.lease_doc(lease, now_s)}

    def move(self, body: object) -> dict[str, Any]:
        descr = _object(body)
        lease = self._find(descr)
        if "valid_from" not in descr and "valid_until" not in descr:
            raise BrokerError(400, "Cannot update lease without valid_from or valid_until.")
        valid_from_s = (
            _time_s("valid_from", descr["valid_from"])
            if "valid_from" in descr
            else lease.valid_from_s
        )
        valid_until_s = (
            _time_s("valid_until", descr["valid_until"])
            if "valid_until" in descr
            else lease.valid_until_s
        )
        self._check_window(valid_from_s, valid_until_s)
        with self.store.lock:
            lease = self.store.by_uuid(lease.uuid) or lease
            now_s = self.clock.now_s()
            status = lease.status(now_s)
            if status in ("cancelled", "past"):
                raise BrokerError(400, f"Lease '{lease.name}' is {status} and cannot be moved.")
            clashes = self._clashes(
                lease.nodes, valid_from_s, valid_until_s, now_s, exclude=lease.uuid
            )
            if clashes:
                node = clashes[0][0]
                code = 400 if self.config.conflict_as == "zombie" else self.config.conflict_code
                raise BrokerError(
                    code, f"Resource '{node}' is not available for the requested timeslot."
                )
            lease = replace(lease, valid_from_s=valid_from_s, valid_until_s=valid_until_s)
            self.store.save(lease)
            return {"resource": self.lease_doc(lease, now_s)}

    def cancel(self, body: object) -> dict[str, Any]:
        descr = _object(body)
        with self.store.lock:
            lease = self._find(descr, label="Lease")
            now_s = self.clock.now_s()
            if lease.state in ("booked", "pending"):
                state = "past" if lease.valid_until_s <= now_s else "cancelled"
                self.store.save(replace(lease, state=state))
        return {"response": "OK"}

    # test control

    def seed(self, body: object) -> dict[str, Any]:
        """A lease as another tool might have left it, without any check (tests only)."""
        descr = _object(body)
        status = descr.get("status", "accepted")
        states = {"pending": "pending", "accepted": "booked", "cancelled": "cancelled"}
        if status not in states:
            raise BrokerError(400, "status must be pending, accepted or cancelled.")
        components = descr.get("components", [])
        if not isinstance(components, list):
            raise BrokerError(400, "Attribute components must be a list.")
        valid_from_s = _time_s("valid_from", descr.get("valid_from"))
        valid_until_s = _time_s("valid_until", descr.get("valid_until"))
        self._check_window(valid_from_s, valid_until_s)
        lease_uuid = str(uuid_lib.uuid4())
        name = descr.get("name", lease_uuid)
        if not isinstance(name, str) or not name:
            raise BrokerError(400, "Attribute name must be a string.")
        lease = StoredLease(
            uuid=lease_uuid,
            name=name,
            valid_from_s=valid_from_s,
            valid_until_s=valid_until_s,
            account=_account(descr),
            state=states[status],
            nodes=self._resolve(components),
        )
        self.store.save(lease)
        return {"resource": self.lease_doc(lease, self.clock.now_s())}

    # pieces

    def lease_doc(self, lease: StoredLease, now_s: float) -> dict[str, Any]:
        domain = self.config.domain
        return {
            "uuid": lease.uuid,
            "urn": f"urn:publicid:IDN+{domain}+lease+{lease.uuid}",
            "name": lease.name,
            "resource_type": "lease",
            "valid_from": _wire(lease.valid_from_s),
            "valid_until": _wire(lease.valid_until_s),
            "status": lease.status(now_s),
            "account": {
                "name": lease.account,
                "urn": f"urn:publicid:IDN+{domain}+account+{lease.account}",
                "resource_type": "account",
            },
            "components": [_node_doc(node, domain) for node in lease.nodes],
        }

    def _listing(self, docs: list[dict[str, Any]]) -> dict[str, Any]:
        if not docs and self.config.empty_as_404:
            raise BrokerError(404, NO_MATCH)
        return {"resources": docs}

    def _check_window(self, valid_from_s: int, valid_until_s: int) -> None:
        if valid_from_s >= valid_until_s:
            raise BrokerError(400, "valid_from must be before valid_until.")
        step = self.config.granularity_s
        if valid_from_s % step or valid_until_s % step:
            raise BrokerError(422, f"Lease times must be aligned to {step}s granularity.")

    def _resolve(self, components: list[Any]) -> tuple[str, ...]:
        """The known nodes among the components; like omf_sfa, unknown ones are left out."""
        found: list[str] = []
        for component in components:
            if not isinstance(component, dict):
                raise BrokerError(400, "Each component is an object with a uuid, name or urn.")
            keys = {key: component[key] for key in ("uuid", "name", "urn") if key in component}
            if not keys:
                raise BrokerError(400, "Each component is an object with a uuid, name or urn.")
            for doc in self.node_docs:
                if all(doc[key] == value for key, value in keys.items()):
                    found.append(doc["name"])
                    break
        return tuple(dict.fromkeys(found))

    def _clashes(
        self,
        nodes: Sequence[str],
        valid_from_s: int,
        valid_until_s: int,
        now_s: float,
        *,
        exclude: str | None,
    ) -> list[tuple[str, StoredLease]]:
        clashes = []
        for node in nodes:
            for other in self.store.all():
                if (
                    other.uuid != exclude
                    and node in other.nodes
                    and other.holds(now_s)
                    and other.valid_from_s < valid_until_s
                    and other.valid_until_s > valid_from_s
                ):
                    clashes.append((node, other))
                    break
        return clashes

    def _clash_reason(self, clashes: list[tuple[str, StoredLease]]) -> str:
        if self.config.conflict_as == "401":
            # omf_sfa names the first node it could not lease, and nothing else.
            return (
                f"Reservation for the resource '{clashes[0][0]}' failed. The resource is "
                "either unavailable or a policy quota has been exceeded."
            )
        names = ", ".join(f"'{node}'" for node, _ in clashes)
        other = clashes[0][1]
        plural = "s" if len(clashes) > 1 else ""
        return (
            f"Reservation for the resource{plural} {names} failed: overlaps lease {other.uuid} "
            f"from {_wire(other.valid_from_s)} until {_wire(other.valid_until_s)}."
        )

    def _find(self, descr: dict[str, Any], *, label: str = "lease") -> StoredLease:
        lease_uuid, name = descr.get("uuid"), descr.get("name")
        lease = None
        if isinstance(lease_uuid, str):
            lease = self.store.by_uuid(lease_uuid)
        elif isinstance(name, str):
            lease = self.store.by_name(name)
        elif lease_uuid is None and name is None:
            raise BrokerError(400, "The lease is named by its uuid or name.")
        if lease is None:
            shown = json.dumps({"uuid": lease_uuid} if lease_uuid is not None else {"name": name})
            raise BrokerError(404, f"Unknown {label} with descr '{shown[:120]}'.")
        return lease


def _node_doc(name: str, domain: str) -> dict[str, Any]:
    urn = f"urn:publicid:IDN+{domain}+node+{name}"
    return {
        "uuid": str(uuid_lib.uuid5(uuid_lib.NAMESPACE_URL, urn)),
        "urn": urn,
        "name": name,
        "resource_type": "node",
        "domain": domain,
        "available": True,
        "exclusive": True,
    }


def _object(body: object) -> dict[str, Any]:
    if not isinstance(body, dict):
        raise BrokerError(400, "The resource description must be a JSON object.")
    return body


def _present(descr: dict[str, Any], key: str) -> Any:
    value = descr.get(key)
    return value if value not in (None, [], {}) else None


def _account(descr: dict[str, Any]) -> str:
    account = _present(descr, "account") or _present(descr, "account_attributes")
    if account is None:
        raise BrokerError(400, "Attribute account is mandatory.")
    name = account.get("name") if isinstance(account, dict) else None
    if not isinstance(name, str) or not 0 < len(name) <= MAX_NAME_CHARS:
        raise BrokerError(400, "Attribute account needs a name.")
    return name


def _time_s(label: str, value: object) -> int:
    """Whole seconds since the epoch; like omf_sfa, fractions of a second are dropped."""
    if not isinstance(value, str):
        raise BrokerError(400, f"Attribute {label} must be a time such as 2026-01-01T10:00:00Z.")
    try:
        moment = datetime.fromisoformat(value.strip())
        if moment.utcoffset() is None:
            moment = moment.replace(tzinfo=UTC)
        in_range = _EARLIEST <= moment < _LATEST
    except (ValueError, OverflowError):
        raise BrokerError(400, f"Invalid time '{value[:40]}' for {label}.") from None
    if not in_range:
        raise BrokerError(400, f"Time '{value[:40]}' for {label} is out of range.")
    return (moment - _EPOCH) // timedelta(seconds=1)


def _wire(seconds: int) -> str:
    return (_EPOCH + timedelta(seconds=seconds)).strftime(WIRE_TIME_FORMAT)


# -- HTTP ---------------------------------------------------------------------------------


def create_app(config: StandinConfig, *, clock: Callable[[], float] = time.time) -> Flask:
    """The stand-in broker as a WSGI app. ``close_app(app)`` closes its SQLite file."""
    app = Flask(__name__)
    app.config["MAX_CONTENT_LENGTH"] = MAX_BODY_BYTES
    app.config["PROVIDE_AUTOMATIC_OPTIONS"] = False
    broker = Broker(config, LeaseStore(config.db_path), Clock(source=clock))
    app.extensions[EXTENSION_KEY] = broker

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

    if config.test_control:
        _register_test_control(app, broker)
    return app


def close_app(app: Flask) -> None:
    app.extensions[EXTENSION_KEY].store.close()


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


# -- the process --------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m bookings.scheduler.standin",
        description="Stand-in omf_sfa broker (leases of the fixed nodes). Flags override "
        f"the {ENV_PREFIX}* variables.",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on")
    parser.add_argument("--port", type=int, default=8710, help="TCP port (0: a free one)")
    parser.add_argument("--threads", type=int, default=8, help="HTTP worker threads")
    parser.add_argument("--log-level", default="INFO")
    parser.add_argument("--conflict-as", choices=CONFLICT_MODES, help="how a clash is answered")
    parser.add_argument("--granularity-s", type=int, help="lease times on multiples of this")
    parser.add_argument(
        "--empty-as-404",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="answer an empty listing as 404",
    )
    parser.add_argument("--token", help="require this bearer token")
    parser.add_argument("--token-file", help="require the bearer token in this file")
    parser.add_argument("--nodes", help="comma-separated node names (default node-01..node-24)")
    parser.add_argument("--db", help="SQLite file that keeps leases across restarts")
    parser.add_argument(
        "--test-control",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="serve /_standin/ endpoints: clock, faults, reset (tests only)",
    )
    return parser


def config_from(args: argparse.Namespace, environ: Mapping[str, str]) -> StandinConfig:
    config = StandinConfig.from_env(environ)
    changes: dict[str, Any] = {}
    if args.conflict_as is not None:
        changes["conflict_as"] = args.conflict_as
    if args.granularity_s is not None:
        changes["granularity_s"] = args.granularity_s
    if args.empty_as_404 is not None:
        changes["empty_as_404"] = args.empty_as_404
    if args.test_control is not None:
        changes["test_control"] = args.test_control
    if args.nodes is not None:
        changes["nodes"] = _node_list(args.nodes)
    if args.db is not None:
        changes["db_path"] = args.db
    if args.token is not None or args.token_file is not None:
        changes["token"] = _token(args.token or "", args.token_file or "", label="--token")
    return replace(config, **changes)


class _Stop(SystemExit):
    """Raised in the main thread by the signal handler; waitress stops serving on it."""


def _raise_stop(signum: int, frame: types.FrameType | None) -> None:
    raise _Stop(0)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        stream=sys.stderr,
        level=args.log_level.upper(),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        config = config_from(args, os.environ)
        app = create_app(config)
    except (ConfigError, sqlite3.Error, OSError) as exc:
        print(f"scheduler stand-in: configuration error: {exc}", file=sys.stderr)
        return 2
    try:
        server = create_server(
            app,
            host=args.host,
            port=args.port,
            threads=args.threads,
            max_request_body_size=MAX_BODY_BYTES,
        )
    except OSError as exc:
        logger.error("cannot listen on %s:%s: %s", args.host, args.port, exc)
        close_app(app)
        return 1
    port = getattr(server, "effective_port", args.port)
    logger.info(
        "scheduler stand-in listening on http://%s:%s (conflicts as %s, granularity %d s, "
        "empty list as %s, auth %s, %d nodes, leases in %s%s)",
        args.host,
        port,
        config.conflict_as,
        config.granularity_s,
        "404" if config.empty_as_404 else "[]",
        "on" if config.token else "off",
        len(config.nodes),
        config.db_path,
        ", test control ON" if config.test_control else "",
    )
    previous = {sig: signal.signal(sig, _raise_stop) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        server.run()
    except _Stop:
        pass
    finally:
        for sig in previous:
            signal.signal(sig, signal.SIG_IGN)
        server.close()
        close_app(app)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    logger.info("scheduler stand-in stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
