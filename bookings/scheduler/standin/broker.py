"""What the stand-in broker does with a call: the omf_sfa broker's rules for nodes and
leases (clashes, the grid, statuses that follow the clock), its words for each refusal, and
the test-only faults and clock it can be given."""

from __future__ import annotations

import json
import time
import uuid as uuid_lib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta
from typing import Any

from bookings.scheduler.standin.config import StandinConfig
from bookings.scheduler.standin.store import LeaseStore, StoredLease

DEFAULT_STATUSES = ("pending", "accepted", "active")
STATUSES = ("pending", "accepted", "active", "past", "cancelled")
MAX_NAME_CHARS = 255
WIRE_TIME_FORMAT = "%Y-%m-%dT%H:%M:%SZ"
NO_MATCH = "No resources matching the request."
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
# Times outside this range are refused rather than risk overflowing on the way back out.
_EARLIEST = datetime(1970, 1, 1, tzinfo=UTC)
_LATEST = datetime(9000, 1, 1, tzinfo=UTC)


class BrokerError(Exception):
    """An answer in the broker's error envelope."""

    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason)
        self.code = code
        self.reason = reason


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
