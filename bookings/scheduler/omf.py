"""The omf_sfa broker's REST dialect ("AM" REST, as run by NITOS and R2lab), over ``requests``.

What a broker says and how this module reads it:

- ``GET /resources/nodes`` lists nodes; ``GET /resources/leases?status=a,b`` lists leases in
  those statuses (the broker's default is ``pending,accepted,active``). Some brokers answer
  an empty list as 404 "No resources matching the request.": that is ``[]`` here. Brokers
  ignore a lease's ``uuid``/``name`` filters, so leases are always filtered here as well.
- ``POST /resources/leases`` creates one lease with many components, all-or-nothing. A
  conflict comes back as 401 with the reason "Reservation for the resource 'X' failed…"
  (omf_sfa), as 409 (other deployments), or as a 200 whose lease holds *no* component
  (older omf_sfa). A 401 whose reason is not about a reservation is a real credentials
  failure. A lease answered with fewer components than asked (omf_sfa skips names it does
  not know) is cancelled again here and refused: the lease is all-or-nothing.
- ``PUT /resources/leases`` names the lease by uuid and carries the new times; a clash is
  the same 401/409, or 400 "Resource 'X' is not available for the requested timeslot."
- ``DELETE /resources/leases`` with ``{"uuid": …}`` marks the lease ``cancelled`` (``past``
  if it had ended) and answers just "OK"; the lease is read back.
- Answers wrap in ``{"resource_response": {"resource": {…}}}`` or ``{…{"resources": […]}}``;
  errors in ``{"exception": {"code": N, "reason": "…"}}`` (sometimes under HTTP 200).

Times go out in UTC as whole seconds with a ``Z``; a lease covers the booking (its start
floored, its end ceiled to the configured granularity). Times that come back without an
offset are read as UTC.
"""

from __future__ import annotations

import json
import logging
import re
import time
from collections.abc import Collection, Sequence
from datetime import UTC, datetime
from typing import Any

import requests

from bookings.scheduler.adapter import (
    ALL_STATUSES,
    LIVE_STATUSES,
    Lease,
    LeaseStatus,
    Node,
    SchedulerAuthFailed,
    SchedulerConflict,
    SchedulerError,
    SchedulerNotFound,
    SchedulerRejected,
    SchedulerUnavailable,
    covering_window,
)
from bookings.scheduler.config import SchedulerConfig

logger = logging.getLogger(__name__)

NODES_PATH = "/resources/nodes"
LEASES_PATH = "/resources/leases"
WIRE_TIME_FORMAT = "%Y-%m-%dT%H:%M:%SZ"

# How brokers word a clash with another lease, whatever HTTP status they put on it.
_CONFLICT_REASON = re.compile(
    r"reservation for the resource|not available|unavailable|overlap|conflict"
    r"|already (?:leased|booked|reserved)",
    re.IGNORECASE,
)
_QUOTED = re.compile(r"'([^']{1,200})'|\"([^\"]{1,200})\"")
# Some brokers write "passed" for "past" (omf_sfa's operational status does).
_STATUS_ALIASES = {"passed": LeaseStatus.PAST}
_MAX_REASON_CHARS = 500


class OmfScheduler:
    """:class:`~bookings.scheduler.adapter.Scheduler` for an omf_sfa broker.

    One instance holds one HTTP session; use one per thread or process.
    """

    def __init__(self, config: SchedulerConfig, *, session: requests.Session | None = None):
        self.config = config
        self._session = session or requests.Session()
        self._session.headers["Accept"] = "application/json"
        if config.token:
            self._session.headers["Authorization"] = f"Bearer {config.token}"
        if config.client_cert is not None:
            self._session.cert = (
                (str(config.client_cert), str(config.client_key))
                if config.client_key is not None
                else str(config.client_cert)
            )
        self._session.verify = str(config.ca_bundle) if config.ca_bundle else config.verify_tls

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> OmfScheduler:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- the Scheduler protocol ----------------------------------------------------------

    def list_nodes(self) -> list[Node]:
        status_code, body = self._call("GET", NODES_PATH)
        return nodes_from_answer(status_code, body)

    def list_leases(
        self,
        *,
        window_start: datetime | None = None,
        window_end: datetime | None = None,
        statuses: Collection[LeaseStatus] = LIVE_STATUSES,
    ) -> list[Lease]:
        for label, value in (("window_start", window_start), ("window_end", window_end)):
            if value is not None and value.utcoffset() is None:
                raise ValueError(f"{label} must be timezone-aware, got {value!r}")
        wanted = _statuses(statuses)
        if not wanted:
            return []
        leases = self._leases(wanted)
        return sorted(
            (
                lease
                for lease in leases
                if lease.status in wanted
                and lease.component_names
                and lease.overlaps(start=window_start, end=window_end)
            ),
            key=lambda lease: (lease.valid_from, lease.uuid),
        )

    def get_lease(self, *, uuid: str | None = None, name: str | None = None) -> Lease | None:
        if not uuid and not name:
            raise ValueError("get_lease needs a uuid or a name")
        params = {"uuid": uuid} if uuid else {"name": name or ""}
        leases = self._leases(ALL_STATUSES, extra_params=params)
        if uuid:
            return next((lease for lease in leases if lease.uuid == uuid), None)
        named = [lease for lease in leases if lease.name == name]
        # A live lease first, then the latest: a retried booking may have left older ones.
        named.sort(key=lambda lease: (lease.status in LIVE_STATUSES, lease.valid_from))
        return named[-1] if named else None

    def create_lease(
        self,
        *,
        name: str,
        valid_from: datetime,
        valid_until: datetime,
        component_names: Sequence[str],
        account_name: str | None = None,
    ) -> Lease:
        if isinstance(component_names, str):
            raise TypeError("component_names is a sequence of names, not one string")
        wanted = tuple(dict.fromkeys(component_names))
        if not wanted:
            raise ValueError("a lease needs at least one component")
        if not name:
            raise ValueError("a lease needs a name")
        start, end = covering_window(
            valid_from=valid_from, valid_until=valid_until, granularity_s=self.config.granularity_s
        )
        body = {
            "name": name,
            "valid_from": wire_time(start),
            "valid_until": wire_time(end),
            "account_attributes": {"name": account_name or self.config.account_name},
            "components": [{"name": node} for node in wanted],
        }
        status_code, answer = self._call("POST", LEASES_PATH, body=body)
        lease = lease_from_answer(status_code, answer, requested=wanted)
        self._check_all_or_nothing(lease, wanted)
        return lease

    def move_lease(self, *, uuid: str, valid_from: datetime, valid_until: datetime) -> Lease:
        if not uuid:
            raise ValueError("move_lease needs the lease's uuid")
        start, end = covering_window(
            valid_from=valid_from, valid_until=valid_until, granularity_s=self.config.granularity_s
        )
        body = {"uuid": uuid, "valid_from": wire_time(start), "valid_until": wire_time(end)}
        status_code, answer = self._call("PUT", LEASES_PATH, body=body)
        return lease_from_answer(status_code, answer)

    def cancel_lease(self, *, uuid: str) -> Lease:
        if not uuid:
            raise ValueError("cancel_lease needs the lease's uuid")
        status_code, answer = self._call("DELETE", LEASES_PATH, body={"uuid": uuid})
        resources = resources_from_answer(status_code, answer)
        if resources:
            return lease_from_resource(resources[0])
        # omf_sfa answers a delete with {"response": "OK"} only: read the lease back.
        lease = self.get_lease(uuid=uuid)
        if lease is None:
            raise SchedulerRejected(f"lease {uuid} was cancelled but the broker no longer lists it")
        return lease

    # -- the wire ------------------------------------------------------------------------

    def _leases(
        self, statuses: Collection[LeaseStatus], *, extra_params: dict[str, str] | None = None
    ) -> list[Lease]:
        params = {"status": ",".join(status.value for status in statuses), **(extra_params or {})}
        status_code, body = self._call("GET", LEASES_PATH, params=params)
        return leases_from_answer(status_code, body)

    def _check_all_or_nothing(self, lease: Lease, wanted: tuple[str, ...]) -> None:
        if not lease.component_names:
            # Older omf_sfa answers a clash with a pending lease that holds nothing.
            self._discard(lease)
            raise SchedulerConflict(
                f"the scheduler answered lease {lease.name} with no components: "
                "the nodes are taken or unknown to it",
                reason="lease answered with an empty component list",
            )
        missing = [node for node in wanted if node not in lease.component_names]
        if missing:
            self._discard(lease)
            raise SchedulerRejected(
                f"the scheduler leased only some of the nodes; {', '.join(missing)} "
                "are unknown to it (the partial lease was cancelled)",
                reason=f"components left out: {', '.join(missing)}",
            )
        if not lease.status.holds_nodes and lease.status is not LeaseStatus.PAST:
            self._discard(lease)
            raise SchedulerRejected(
                f"the scheduler answered lease {lease.name} as {lease.status}, not accepted",
                reason=f"lease status {lease.status}",
            )

    def _discard(self, lease: Lease) -> None:
        """Cancel a lease the broker made but we refuse; failing that, the reconciler will."""
        try:
            status_code, answer = self._call("DELETE", LEASES_PATH, body={"uuid": lease.uuid})
            resources_from_answer(status_code, answer)
        except SchedulerError as exc:
            logger.warning("could not cancel the refused lease %s: %s", lease.uuid, exc)

    def _call(
        self,
        method: str,
        path: str,
        *,
        params: dict[str, str] | None = None,
        body: dict[str, Any] | None = None,
    ) -> tuple[int, bytes]:
        """One request and its answer, whatever its status; no answer is SchedulerUnavailable."""
        url = f"{self.config.base_url}{path}"
        started_s = time.monotonic()
        try:
            response = self._session.request(
                method, url, params=params, json=body, timeout=self.config.timeouts_s
            )
        except requests.exceptions.SSLError as exc:
            raise SchedulerAuthFailed(f"TLS with the scheduler at {url} failed: {exc}") from exc
        except requests.Timeout as exc:
            raise SchedulerUnavailable(
                f"the scheduler at {url} did not answer within "
                f"{self.config.connect_timeout_s:g} s (connect) / "
                f"{self.config.read_timeout_s:g} s (read)"
            ) from exc
        except requests.TooManyRedirects as exc:
            raise SchedulerRejected(f"the scheduler at {url} redirects in circles") from exc
        except requests.RequestException as exc:
            raise SchedulerUnavailable(f"cannot reach the scheduler at {url}: {exc}") from exc
        logger.debug(
            "scheduler %s %s -> %s in %.0f ms",
            method,
            path,
            response.status_code,
            (time.monotonic() - started_s) * 1000,
        )
        return response.status_code, response.content


# -- reading answers (pure functions: no network, every failure a SchedulerError) --------


def wire_time(moment: datetime) -> str:
    """UTC, whole seconds, ``Z`` — how brokers write times."""
    if moment.utcoffset() is None:
        raise ValueError(f"a wire time must be timezone-aware, got {moment!r}")
    return moment.astimezone(UTC).strftime(WIRE_TIME_FORMAT)


def parse_wire_time(value: object) -> datetime:
    if not isinstance(value, str) or not value:
        raise SchedulerRejected(f"bad answer: {value!r} is not a time")
    try:
        moment = datetime.fromisoformat(value.strip())
        if moment.utcoffset() is None:
            moment = moment.replace(tzinfo=UTC)
        return moment.astimezone(UTC)
    except (ValueError, OverflowError):
        raise SchedulerRejected(f"bad answer: {value[:60]!r} is not an ISO 8601 time") from None


def error_from_answer(
    status_code: int, payload: object, *, requested: Sequence[str] = ()
) -> SchedulerError:
    """The error a non-2xx answer (or a 2xx carrying an ``exception``) stands for."""
    reason = _reason(payload)
    where = f"the scheduler answered {status_code}" + (f": {reason}" if reason else "")
    if status_code >= 500 or status_code in (408, 429):
        return SchedulerUnavailable(where, reason=reason, status_code=status_code)
    if status_code == 409 or (
        status_code in (400, 401, 403, 422) and _CONFLICT_REASON.search(reason)
    ):
        return SchedulerConflict(
            where,
            node_names=_nodes_named(reason, requested),
            reason=reason,
            status_code=status_code,
        )
    if status_code in (401, 403):
        return SchedulerAuthFailed(where, reason=reason, status_code=status_code)
    if status_code == 404:
        return SchedulerNotFound(where, reason=reason, status_code=status_code)
    return SchedulerRejected(where, reason=reason, status_code=status_code)


def resources_from_answer(
    status_code: int,
    body: bytes,
    *,
    not_found_is_empty: bool = False,
    requested: Sequence[str] = (),
) -> list[dict[str, Any]]:
    """The resource objects of an answer: ``[]`` for "OK"-only answers.

    With ``not_found_is_empty``, a 404 in the broker's error envelope is an empty list (how
    some brokers answer ``[]``); a bare 404 (a wrong URL, a proxy's page) stays an error.
    ``requested`` are the nodes asked for, to recognise them in a conflict's reason.
    """
    payload = _json_or_none(body)
    exception = _exception_code(payload)
    if exception is not None or not 200 <= status_code < 300:
        code = exception if exception is not None and status_code < 300 else status_code
        if code == 404 and not_found_is_empty and exception is not None:
            return []
        raise error_from_answer(code, payload, requested=requested)
    if not isinstance(payload, dict):
        raise SchedulerRejected(f"bad answer: not a JSON object: {_snippet(body)}")
    inner = payload.get("resource_response", payload)
    if not isinstance(inner, dict):
        raise SchedulerRejected("bad answer: resource_response is not an object")
    if "resources" in inner:
        listed = inner["resources"]
        if not isinstance(listed, list):
            raise SchedulerRejected("bad answer: resources is not a list")
        if not all(isinstance(item, dict) for item in listed):
            raise SchedulerRejected("bad answer: resources holds something that is not an object")
        return listed
    if "resource" in inner:
        single = inner["resource"]
        if not isinstance(single, dict):
            raise SchedulerRejected("bad answer: resource is not an object")
        return [single]
    if "response" in inner:
        return []
    raise SchedulerRejected("bad answer: neither resource, resources nor response")


def leases_from_answer(status_code: int, body: bytes) -> list[Lease]:
    """Every well-formed lease of a listing; malformed ones are logged and left out."""
    leases = []
    for resource in resources_from_answer(status_code, body, not_found_is_empty=True):
        try:
            leases.append(lease_from_resource(resource))
        except SchedulerRejected as exc:
            logger.warning("scheduler listed a lease this portal cannot read: %s", exc)
    return leases


def lease_from_answer(status_code: int, body: bytes, *, requested: Sequence[str] = ()) -> Lease:
    """The one lease of a create/move answer."""
    resources = resources_from_answer(status_code, body, requested=requested)
    if len(resources) != 1:
        raise SchedulerRejected(f"bad answer: expected one lease, got {len(resources)}")
    return lease_from_resource(resources[0])


def nodes_from_answer(status_code: int, body: bytes) -> list[Node]:
    nodes = []
    for resource in resources_from_answer(status_code, body, not_found_is_empty=True):
        name = resource.get("name")
        uuid = resource.get("uuid")
        if not isinstance(name, str) or not name or not isinstance(uuid, str):
            raise SchedulerRejected(f"bad answer: a node without a name or uuid: {resource!r:.200}")
        urn = resource.get("urn")
        nodes.append(
            Node(
                uuid=uuid,
                name=name,
                urn=urn if isinstance(urn, str) else "",
                available=resource.get("available", True) is not False,
                exclusive=resource.get("exclusive", True) is not False,
            )
        )
    return nodes


def lease_from_resource(resource: dict[str, Any]) -> Lease:
    uuid = resource.get("uuid")
    if not isinstance(uuid, str) or not uuid:
        raise SchedulerRejected("bad answer: a lease without a uuid")
    name = resource.get("name", uuid)
    if not isinstance(name, str):
        raise SchedulerRejected(f"bad answer: lease {uuid} has a name that is not a string")
    valid_from = parse_wire_time(resource.get("valid_from"))
    valid_until = parse_wire_time(resource.get("valid_until"))
    if valid_from >= valid_until:
        raise SchedulerRejected(f"bad answer: lease {uuid} ends before it starts")
    raw_status = resource.get("status")
    if not isinstance(raw_status, str):
        raise SchedulerRejected(f"bad answer: lease {uuid} has no status")
    status = _STATUS_ALIASES.get(raw_status.lower())
    if status is None:
        try:
            status = LeaseStatus(raw_status.lower())
        except ValueError:
            raise SchedulerRejected(
                f"bad answer: lease {uuid} has the unknown status {raw_status[:40]!r}"
            ) from None
    account = resource.get("account")
    account_name = account.get("name") if isinstance(account, dict) else None
    components = resource.get("components") or []
    if not isinstance(components, list):
        raise SchedulerRejected(f"bad answer: lease {uuid} has components that are not a list")
    return Lease(
        uuid=uuid,
        name=name,
        valid_from=valid_from,
        valid_until=valid_until,
        status=status,
        account_name=account_name if isinstance(account_name, str) else "",
        component_names=tuple(_component_name(uuid, c) for c in components),
    )


def _component_name(lease_uuid: str, component: object) -> str:
    if isinstance(component, dict):
        for key in ("name", "urn", "uuid"):
            value = component.get(key)
            if isinstance(value, str) and value:
                # An urn ends in the name: urn:publicid:IDN+amazing+node+node-01.
                return value.rsplit("+", 1)[-1] if key == "urn" else value
    if isinstance(component, str) and component:
        return component
    raise SchedulerRejected(f"bad answer: lease {lease_uuid} has an unnamed component")


def _statuses(statuses: Collection[LeaseStatus]) -> tuple[LeaseStatus, ...]:
    if isinstance(statuses, str):
        raise TypeError("statuses is a collection of LeaseStatus, not one string")
    return tuple(LeaseStatus(status) for status in dict.fromkeys(statuses))


def _json_or_none(body: bytes) -> object:
    try:
        return json.loads(body)
    except (ValueError, RecursionError):
        return None


def _exception_code(payload: object) -> int | None:
    """The code of an ``{"exception": {...}}`` envelope, if that is what the payload is."""
    if not isinstance(payload, dict):
        return None
    exception = payload.get("exception")
    if not isinstance(exception, dict):
        return None
    code = exception.get("code")
    try:
        number = int(code) if isinstance(code, int | str) and not isinstance(code, bool) else 0
    except ValueError:
        number = 0
    return number if 400 <= number <= 599 else 400


def _reason(payload: object) -> str:
    reason: object = ""
    if isinstance(payload, dict):
        for key in ("exception", "error"):
            value = payload.get(key)
            if isinstance(value, dict):
                reason = value.get("reason", "")
                break
            if isinstance(value, str):
                reason = value
                break
    if not isinstance(reason, str):
        reason = json.dumps(reason, default=str)
    return reason.strip()[:_MAX_REASON_CHARS]


def _nodes_named(reason: str, requested: Sequence[str]) -> tuple[str, ...]:
    """The nodes a conflict's reason names: the requested ones it mentions, else its quotes."""
    named = [
        node for node in requested if re.search(rf"(?<![\w-]){re.escape(node)}(?![\w-])", reason)
    ]
    if named:
        return tuple(named)
    quoted = (single or double for single, double in _QUOTED.findall(reason))
    return tuple(dict.fromkeys(quoted))


def _snippet(body: bytes) -> str:
    return repr(body[:80])
