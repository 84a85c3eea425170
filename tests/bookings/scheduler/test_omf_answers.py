"""How the omf_sfa adapter reads brokers' answers, from the exact bytes (no network)."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta, timezone

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bookings.scheduler import (
    LeaseStatus,
    SchedulerAuthFailed,
    SchedulerConflict,
    SchedulerError,
    SchedulerNotFound,
    SchedulerRejected,
    SchedulerUnavailable,
    covering_window,
)
from bookings.scheduler.omf import (
    error_from_answer,
    lease_from_answer,
    leases_from_answer,
    nodes_from_answer,
    resources_from_answer,
    wire_time,
)

RESERVATION_FAILED = (
    "Reservation for the resource 'node-03' failed. The resource is either unavailable or a "
    "policy quota has been exceeded."
)


def envelope(code: int, reason: str) -> bytes:
    return json.dumps({"exception": {"code": code, "reason": reason}}).encode()


def lease_doc(**changes: object) -> dict[str, object]:
    doc: dict[str, object] = {
        "uuid": "ee3614fb-74d2-4097-99c5-fe0b988f2f2d",
        "urn": "urn:publicid:IDN+omf:r2lab+lease+ee3614fb-74d2-4097-99c5-fe0b988f2f2d",
        "resource_type": "lease",
        "valid_from": "2015-11-26T10:30:00Z",
        "valid_until": "2015-11-26T11:30:00Z",
        "status": "accepted",
        "client_id": "b089e80a-3b0a-4580-86ba-aacff6e4043e",
        "components": [
            {"name": "node-03", "urn": "urn:publicid:IDN+omf:r2lab+node+node-03", "uuid": "u3"}
        ],
        "account": {"name": "onelab.inria.foo1", "uuid": "6a49945c"},
    }
    doc.update(changes)
    return doc


def wrapped(*docs: dict[str, object], single: bool = False) -> bytes:
    inner = {"resource": docs[0]} if single else {"resources": list(docs)}
    return json.dumps({"resource_response": {**inner, "about": "/resources/leases"}}).encode()


@pytest.mark.parametrize(
    ("status", "body", "expected"),
    [
        (401, envelope(401, RESERVATION_FAILED), SchedulerConflict),
        (409, envelope(409, "Overlaps with lease 12 (slice, 10:00 — 11:00)"), SchedulerConflict),
        (409, b"<html>conflict</html>", SchedulerConflict),
        (
            400,
            envelope(400, "Resource 'node-03' is not available for the requested timeslot."),
            SchedulerConflict,
        ),
        (401, envelope(401, "Missing peer cert"), SchedulerAuthFailed),
        (401, envelope(401, "OMF::SFA::AM::InsufficientPrivilegesException"), SchedulerAuthFailed),
        (403, b"Forbidden", SchedulerAuthFailed),
        (404, envelope(404, "Unknown Lease with descr'{:uuid=>\"x\"}'."), SchedulerNotFound),
        (422, envelope(422, "Lease times must be aligned to 600s granularity"), SchedulerRejected),
        (400, envelope(400, "Attribute account is mandatory."), SchedulerRejected),
        (500, json.dumps({"error": {"reason": "boom", "bt": []}}).encode(), SchedulerUnavailable),
        (502, b"<html>Bad gateway</html>", SchedulerUnavailable),
        (503, b"", SchedulerUnavailable),
        (429, b"slow down", SchedulerUnavailable),
        # Some brokers put the error envelope under a 200.
        (200, envelope(401, RESERVATION_FAILED), SchedulerConflict),
        (200, b"not json", SchedulerRejected),
        (200, b"[]", SchedulerRejected),
        (200, json.dumps({"resource_response": {"resources": [1, 2]}}).encode(), SchedulerRejected),
    ],
)
def test_each_answer_is_the_error_it_stands_for(
    status: int, body: bytes, expected: type[SchedulerError]
) -> None:
    with pytest.raises(SchedulerError) as caught:
        lease_from_answer(status, body, requested=["node-02", "node-03"])
    assert type(caught.value) is expected
    assert caught.value.retryable is (expected is SchedulerUnavailable)


def test_a_conflict_names_the_requested_nodes_its_reason_mentions() -> None:
    error = error_from_answer(
        401, json.loads(envelope(401, RESERVATION_FAILED)), requested=["node-02", "node-03"]
    )
    assert isinstance(error, SchedulerConflict)
    assert error.node_names == ("node-03",)
    several = error_from_answer(
        409,
        {"exception": {"code": 409, "reason": "resources node-1 and node-10 overlap"}},
        requested=["node-1", "node-10", "node-100"],
    )
    assert isinstance(several, SchedulerConflict)
    assert several.node_names == ("node-1", "node-10")
    # Without knowing what was asked, the quoted names are the best guess.
    unknown = error_from_answer(409, {"exception": {"reason": "'node-07' is taken"}})
    assert isinstance(unknown, SchedulerConflict)
    assert unknown.node_names == ("node-07",)
    silent = error_from_answer(409, None)
    assert isinstance(silent, SchedulerConflict)
    assert silent.node_names == ()


def test_an_empty_listing_answered_as_404_is_empty_but_a_bare_404_is_not() -> None:
    no_match = envelope(404, "No resources matching the request.")
    assert leases_from_answer(404, no_match) == []
    assert leases_from_answer(200, no_match) == []
    assert nodes_from_answer(404, no_match) == []
    assert leases_from_answer(200, b'{"resource_response": {"resources": []}}') == []
    # A 404 that is not the broker's envelope is a wrong URL, not an empty calendar.
    with pytest.raises(SchedulerNotFound):
        leases_from_answer(404, b"<html>Not Found</html>")


def test_it_reads_omf_sfa_leases_as_r2lab_lists_them() -> None:
    (lease,) = leases_from_answer(200, wrapped(lease_doc()))
    assert lease.uuid == "ee3614fb-74d2-4097-99c5-fe0b988f2f2d"
    assert lease.name == lease.uuid  # omf_sfa names a lease by its uuid when given no name
    assert lease.valid_from == datetime(2015, 11, 26, 10, 30, tzinfo=UTC)
    assert lease.valid_until - lease.valid_from == timedelta(hours=1)
    assert lease.status is LeaseStatus.ACCEPTED
    assert lease.account_name == "onelab.inria.foo1"
    assert lease.component_names == ("node-03",)
    assert lease.holds_nodes


def test_it_reads_offsets_fractions_aliases_and_components_named_by_urn_only() -> None:
    doc = lease_doc(
        name="r-9",
        valid_from="2014-03-04T20:05:04+02:00",
        valid_until="2014-03-04 21:05:04.250",
        status="passed",
        components=[{"urn": "urn:publicid:IDN+amazing+node+node-12"}, {"uuid": "u-1"}],
        account=None,
    )
    lease = lease_from_answer(200, wrapped(doc, single=True))
    assert lease.valid_from == datetime(2014, 3, 4, 18, 5, 4, tzinfo=UTC)
    assert lease.valid_until == datetime(2014, 3, 4, 21, 5, 4, 250000, tzinfo=UTC)
    assert lease.status is LeaseStatus.PAST
    assert lease.component_names == ("node-12", "u-1")
    assert lease.account_name == ""


def test_a_listing_leaves_out_leases_it_cannot_read_and_keeps_the_rest() -> None:
    broken = lease_doc(uuid="broken", status="exploded")
    good = lease_doc(uuid="good")
    assert [lease.uuid for lease in leases_from_answer(200, wrapped(broken, good))] == ["good"]
    with pytest.raises(SchedulerRejected, match="unknown status"):
        lease_from_answer(200, wrapped(broken, single=True))
    with pytest.raises(SchedulerRejected, match="ends before it starts"):
        lease_from_answer(200, wrapped(lease_doc(valid_until="2015-11-26T10:30:00Z"), single=True))


def test_a_delete_answered_ok_has_no_resource() -> None:
    body = b'{"resource_response": {"response": "OK", "about": "/resources/leases"}}'
    assert resources_from_answer(200, body) == []


def at(clock: str) -> datetime:
    return datetime.fromisoformat(f"2030-06-01T{clock}").replace(tzinfo=UTC)


@pytest.mark.parametrize(
    ("start", "end", "granularity_s", "expected"),
    [
        (at("10:00:00.400000"), at("11:00:05.000001"), 1, (at("10:00:00"), at("11:00:06"))),
        (at("10:00:00"), at("11:00:00"), 1, (at("10:00:00"), at("11:00:00"))),
        (at("10:05:00"), at("10:47:00"), 600, (at("10:00:00"), at("10:50:00"))),
        (at("10:00:00"), at("10:50:00"), 600, (at("10:00:00"), at("10:50:00"))),
        (
            at("23:59:59.999999"),
            at("23:59:59.999999") + timedelta(microseconds=1),
            1,
            (at("23:59:59"), at("00:00:00") + timedelta(days=1)),
        ),
    ],
)
def test_a_lease_window_covers_the_booking(
    start: datetime, end: datetime, granularity_s: int, expected: tuple[datetime, datetime]
) -> None:
    got = covering_window(valid_from=start, valid_until=end, granularity_s=granularity_s)
    assert got == expected
    assert all(moment.tzinfo is UTC for moment in got)


def test_a_lease_window_refuses_naive_or_empty_windows() -> None:
    with pytest.raises(ValueError, match="timezone-aware"):
        covering_window(valid_from=datetime(2030, 1, 1), valid_until=at("10:00:00"))
    with pytest.raises(ValueError, match="before"):
        covering_window(valid_from=at("10:00:00"), valid_until=at("10:00:00"))


def test_wire_times_are_utc_whole_seconds_with_a_z() -> None:
    lisbon_summer = timezone(timedelta(hours=1))
    assert wire_time(datetime(2030, 6, 1, 11, 0, 0, 999999, tzinfo=lisbon_summer)) == (
        "2030-06-01T10:00:00Z"
    )
    with pytest.raises(ValueError, match="timezone-aware"):
        wire_time(datetime(2030, 6, 1))


# -- whatever a broker answers, the adapter answers leases or a SchedulerError -----------

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False)
    | st.text(max_size=30)
    | st.sampled_from(["2030-01-01T10:00:00Z", "accepted", "passed", "node-01", "resource"]),
    lambda children: (
        st.lists(children, max_size=4)
        | st.dictionaries(
            st.sampled_from(
                [
                    "resource_response",
                    "resource",
                    "resources",
                    "response",
                    "exception",
                    "error",
                    "code",
                    "reason",
                    "uuid",
                    "name",
                    "urn",
                    "valid_from",
                    "valid_until",
                    "status",
                    "account",
                    "components",
                    "available",
                ]
            )
            | st.text(max_size=8),
            children,
            max_size=6,
        )
    ),
    max_leaves=25,
)
statuses = st.sampled_from([200, 201, 204, 400, 401, 403, 404, 408, 409, 422, 429, 500, 503])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(status=statuses, payload=json_values)
def test_any_json_answer_is_leases_or_a_scheduler_error(status: int, payload: object) -> None:
    body = json.dumps(payload).encode()
    for read in (leases_from_answer, lease_from_answer, nodes_from_answer, resources_from_answer):
        try:
            result = read(status, body)
        except SchedulerError:
            continue
        assert result is not None


@settings(max_examples=100, deadline=None)
@given(status=statuses, body=st.binary(max_size=200))
def test_any_bytes_answer_is_leases_or_a_scheduler_error(status: int, body: bytes) -> None:
    try:
        leases = leases_from_answer(status, body)
    except SchedulerError:
        return
    assert isinstance(leases, list)


moments = st.datetimes(
    min_value=datetime(1990, 1, 1), max_value=datetime(2100, 1, 1), timezones=st.just(UTC)
).map(lambda moment: moment.replace(microsecond=0))


@settings(max_examples=200, deadline=None)
@given(
    start=moments,
    length_s=st.integers(min_value=1, max_value=10**7),
    status=st.sampled_from(list(LeaseStatus)),
    name=st.text(min_size=1, max_size=40),
    nodes=st.lists(st.from_regex(r"node-[0-9]{2}", fullmatch=True), max_size=5, unique=True),
    offset_h=st.integers(min_value=-12, max_value=14),
)
def test_a_well_formed_lease_reads_back_exactly(
    start: datetime, length_s: int, status: LeaseStatus, name: str, nodes: list[str], offset_h: int
) -> None:
    end = start + timedelta(seconds=length_s)
    zone = timezone(timedelta(hours=offset_h))
    doc = lease_doc(
        name=name,
        valid_from=start.astimezone(zone).isoformat(),
        valid_until=wire_time(end),
        status=status.value,
        components=[{"name": node} for node in nodes],
        account={"name": "amazing"},
    )
    lease = lease_from_answer(200, wrapped(doc, single=True))
    assert (lease.valid_from, lease.valid_until) == (start, end)
    assert lease.valid_from.tzinfo is UTC
    assert lease.status is status
    assert lease.name == name
    assert lease.component_names == tuple(nodes)
