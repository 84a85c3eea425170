"""The omf_sfa adapter against the stand-in broker running as its own process, over HTTP."""

from __future__ import annotations

import threading
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from bookings.scheduler import (
    LeaseStatus,
    SchedulerAuthFailed,
    SchedulerConflict,
    SchedulerError,
    SchedulerNotFound,
    SchedulerRejected,
    SchedulerUnavailable,
)
from bookings.scheduler.config import SchedulerConfig
from bookings.scheduler.omf import OmfScheduler
from tests.bookings.scheduler.conftest import Standin, start_standin, unused_url

pytestmark = pytest.mark.integration

HOUR = timedelta(hours=1)


def test_it_lists_the_24_fixed_nodes_with_uuids_and_urns(standin: Standin) -> None:
    with standin.scheduler() as scheduler:
        nodes = scheduler.list_nodes()
    assert [node.name for node in nodes] == [f"node-{i:02d}" for i in range(1, 25)]
    assert nodes[0].urn == "urn:publicid:IDN+amazing+node+node-01"
    assert len({node.uuid for node in nodes}) == 24
    assert all(node.available and node.exclusive for node in nodes)


def test_a_lease_holds_every_node_and_covers_the_booking(
    standin: Standin, tomorrow: datetime
) -> None:
    start = tomorrow + timedelta(microseconds=400_000)
    end = tomorrow + HOUR + timedelta(seconds=5, microseconds=1)
    with standin.scheduler() as scheduler:
        lease = scheduler.create_lease(
            name="reservation-17",
            valid_from=start,
            valid_until=end,
            component_names=["node-01", "node-02"],
        )
        # The lease covers the booking: its start floored, its end ceiled, to whole seconds.
        assert lease.valid_from == tomorrow
        assert lease.valid_until == tomorrow + HOUR + timedelta(seconds=6)
        assert lease.valid_from.utcoffset() == timedelta(0)
        assert lease.status is LeaseStatus.ACCEPTED
        assert lease.name == "reservation-17"
        assert lease.account_name == "amazing"
        assert lease.component_names == ("node-01", "node-02")
        assert scheduler.get_lease(uuid=lease.uuid) == lease
        assert scheduler.get_lease(name="reservation-17") == lease


def test_it_lists_the_leases_overlapping_a_window_half_open(
    standin: Standin, tomorrow: datetime
) -> None:
    with standin.scheduler() as scheduler:
        early, middle, late = (
            scheduler.create_lease(
                name=name,
                valid_from=tomorrow + k * HOUR,
                valid_until=tomorrow + (k + 1) * HOUR,
                component_names=["node-05"],
            )
            for k, name in enumerate(["early", "middle", "late"])
        )
        window = scheduler.list_leases(window_start=tomorrow + HOUR, window_end=tomorrow + 2 * HOUR)
        assert [lease.name for lease in window] == ["middle"]
        spanning = scheduler.list_leases(
            window_start=tomorrow + HOUR / 2, window_end=tomorrow + 2 * HOUR + timedelta(seconds=1)
        )
        assert [lease.uuid for lease in spanning] == [early.uuid, middle.uuid, late.uuid]
        assert [lease.name for lease in scheduler.list_leases()] == ["early", "middle", "late"]


def test_a_clash_is_a_conflict_naming_the_node_whether_401_or_409(
    standin: Standin, tomorrow: datetime
) -> None:
    with standin.scheduler() as scheduler:
        scheduler.create_lease(
            name="first",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-01", "node-02"],
        )
        with pytest.raises(SchedulerConflict) as caught:
            scheduler.create_lease(
                name="second",
                valid_from=tomorrow + HOUR / 2,
                valid_until=tomorrow + 2 * HOUR,
                component_names=["node-03", "node-02"],
            )
        assert caught.value.node_names == ("node-02",)
        assert caught.value.status_code == int(standin.args[1])
        assert not caught.value.retryable
        assert "node-02" in caught.value.reason
        # All-or-nothing: node-03, which was free, was not leased either.
        assert [lease.name for lease in scheduler.list_leases()] == ["first"]
        assert scheduler.get_lease(name="second") is None


def test_back_to_back_leases_do_not_clash(standin: Standin, tomorrow: datetime) -> None:
    with standin.scheduler() as scheduler:
        for k in range(3):
            scheduler.create_lease(
                name=f"slot-{k}",
                valid_from=tomorrow + k * HOUR,
                valid_until=tomorrow + (k + 1) * HOUR,
                component_names=["node-07"],
            )
        assert len(scheduler.list_leases(statuses=[LeaseStatus.ACCEPTED])) == 3


def test_cancelled_pending_and_past_leases_do_not_block(
    standin: Standin, tomorrow: datetime
) -> None:
    with standin.scheduler() as scheduler:
        cancelled = scheduler.create_lease(
            name="cancelled",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-10"],
        )
        scheduler.cancel_lease(uuid=cancelled.uuid)
        standin.seed(
            name="pending",
            status="pending",
            valid_from=tomorrow.isoformat(),
            valid_until=(tomorrow + HOUR).isoformat(),
            account={"name": "elsewhere"},
            components=[{"name": "node-10"}],
        )
        assert scheduler.get_lease(name="pending").status is LeaseStatus.PENDING  # type: ignore[union-attr]
        again = scheduler.create_lease(
            name="again",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-10"],
        )
        assert again.status is LeaseStatus.ACCEPTED

        # Once the broker's clock is past it, a lease no longer holds its node.
        standin.set_clock(tomorrow + 2 * HOUR)
        assert scheduler.get_lease(uuid=again.uuid).status is LeaseStatus.PAST  # type: ignore[union-attr]
        late = scheduler.create_lease(
            name="late",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-10"],
        )
        assert late.status is LeaseStatus.PAST


def test_moving_a_lease_checks_the_new_times_again(standin: Standin, tomorrow: datetime) -> None:
    with standin.scheduler() as scheduler:
        scheduler.create_lease(
            name="fixed",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-11"],
        )
        mover = scheduler.create_lease(
            name="mover",
            valid_from=tomorrow + 2 * HOUR,
            valid_until=tomorrow + 3 * HOUR,
            component_names=["node-11", "node-12"],
        )
        with pytest.raises(SchedulerConflict) as caught:
            scheduler.move_lease(
                uuid=mover.uuid, valid_from=tomorrow + HOUR / 2, valid_until=tomorrow + 2 * HOUR
            )
        assert caught.value.node_names == ("node-11",)
        assert scheduler.get_lease(uuid=mover.uuid) == mover

        # Right after the other lease is free, and it may grow over its own old slot.
        moved = scheduler.move_lease(
            uuid=mover.uuid, valid_from=tomorrow + HOUR, valid_until=tomorrow + 3 * HOUR
        )
        assert (moved.valid_from, moved.valid_until) == (tomorrow + HOUR, tomorrow + 3 * HOUR)
        assert moved.status is LeaseStatus.ACCEPTED
        assert scheduler.get_lease(uuid=mover.uuid) == moved


def test_cancelling_a_future_lease_answers_it_cancelled(
    standin: Standin, tomorrow: datetime
) -> None:
    with standin.scheduler() as scheduler:
        lease = scheduler.create_lease(
            name="to-cancel",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-13"],
        )
        cancelled = scheduler.cancel_lease(uuid=lease.uuid)
        assert cancelled.uuid == lease.uuid
        assert cancelled.status is LeaseStatus.CANCELLED
        assert scheduler.list_leases() == []
        # Cancelling again changes nothing; an unknown lease is not found.
        assert scheduler.cancel_lease(uuid=lease.uuid).status is LeaseStatus.CANCELLED
        with pytest.raises(SchedulerNotFound):
            scheduler.cancel_lease(uuid="00000000-0000-0000-0000-000000000000")


def test_cancelling_a_lease_that_has_ended_answers_it_past(
    standin: Standin, tomorrow: datetime
) -> None:
    with standin.scheduler() as scheduler:
        lease = scheduler.create_lease(
            name="ended",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-14"],
        )
        standin.set_clock(tomorrow + HOUR)
        assert scheduler.cancel_lease(uuid=lease.uuid).status is LeaseStatus.PAST


def test_the_status_follows_the_brokers_clock(standin: Standin, tomorrow: datetime) -> None:
    with standin.scheduler() as scheduler:
        lease = scheduler.create_lease(
            name="clocked",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-15"],
        )
        seen = []
        for moment in (tomorrow - HOUR, tomorrow, tomorrow + HOUR - timedelta(seconds=1)):
            standin.set_clock(moment)
            seen.append(scheduler.get_lease(uuid=lease.uuid).status)  # type: ignore[union-attr]
        standin.set_clock(tomorrow + HOUR)
        seen.append(scheduler.get_lease(uuid=lease.uuid).status)  # type: ignore[union-attr]
        assert seen == [
            LeaseStatus.ACCEPTED,
            LeaseStatus.ACTIVE,
            LeaseStatus.ACTIVE,
            LeaseStatus.PAST,
        ]
        # The default listing (pending, accepted, active) no longer has it.
        assert scheduler.list_leases() == []
        assert [x.uuid for x in scheduler.list_leases(statuses=[LeaseStatus.PAST])] == [lease.uuid]


def test_an_empty_listing_is_empty_whether_answered_404_or_not(standin: Standin) -> None:
    with standin.scheduler() as scheduler:
        assert scheduler.list_leases() == []
        assert scheduler.get_lease(uuid="9c7e0c5e-0000-4000-8000-000000000000") is None
        assert scheduler.get_lease(name="nothing") is None


def test_a_wrong_token_is_an_auth_error_not_a_conflict(
    omf_sfa: Standin, tomorrow: datetime
) -> None:
    for token in ("wrong-token", None):
        with omf_sfa.scheduler(token=token) as scheduler:
            with pytest.raises(SchedulerAuthFailed) as caught:
                scheduler.create_lease(
                    name="sneaky",
                    valid_from=tomorrow,
                    valid_until=tomorrow + HOUR,
                    component_names=["node-01"],
                )
            assert caught.value.status_code == 401
            assert not isinstance(caught.value, SchedulerConflict)
            assert not caught.value.retryable
            with pytest.raises(SchedulerAuthFailed):
                scheduler.list_nodes()
    with omf_sfa.scheduler() as scheduler:
        assert scheduler.list_leases() == []


def test_a_broker_that_is_not_there_is_unavailable(tomorrow: datetime) -> None:
    config = SchedulerConfig(base_url=unused_url(), connect_timeout_s=2.0)
    with OmfScheduler(config) as scheduler:
        with pytest.raises(SchedulerUnavailable) as caught:
            scheduler.create_lease(
                name="nowhere",
                valid_from=tomorrow,
                valid_until=tomorrow + HOUR,
                component_names=["node-01"],
            )
        assert caught.value.retryable
        assert caught.value.status_code is None
        with pytest.raises(SchedulerUnavailable):
            scheduler.list_leases()


def test_a_broker_that_stopped_is_unavailable_and_a_restart_keeps_its_leases(
    tmp_path: Path, tomorrow: datetime
) -> None:
    db = str(tmp_path / "leases.sqlite3")
    first = start_standin("--db", db)
    try:
        with first.scheduler() as scheduler:
            lease = scheduler.create_lease(
                name="durable",
                valid_from=tomorrow,
                valid_until=tomorrow + HOUR,
                component_names=["node-20", "node-21"],
            )
    finally:
        assert first.stop() == 0
    with first.scheduler() as scheduler, pytest.raises(SchedulerUnavailable):
        scheduler.list_leases()

    second = start_standin("--db", db)
    try:
        with second.scheduler() as scheduler:
            assert scheduler.get_lease(uuid=lease.uuid) == lease
            with pytest.raises(SchedulerConflict):
                scheduler.create_lease(
                    name="clash",
                    valid_from=tomorrow,
                    valid_until=tomorrow + HOUR,
                    component_names=["node-21"],
                )
    finally:
        second.stop()


def test_a_slow_answer_beyond_the_read_timeout_is_unavailable(
    omf_sfa: Standin, tomorrow: datetime
) -> None:
    omf_sfa.faults(delay_s=2.0)
    with omf_sfa.scheduler(read_timeout_s=0.3) as scheduler:
        with pytest.raises(SchedulerUnavailable) as caught:
            scheduler.list_leases()
        assert caught.value.retryable
        assert "did not answer" in caught.value.message
    omf_sfa.faults(delay_s=0.0)
    with omf_sfa.scheduler(read_timeout_s=0.3) as scheduler:
        assert len(scheduler.list_nodes()) == 24


def test_a_broker_refusing_with_503_is_unavailable(omf_sfa: Standin, tomorrow: datetime) -> None:
    omf_sfa.faults(unavailable=True)
    with omf_sfa.scheduler() as scheduler:
        with pytest.raises(SchedulerUnavailable) as caught:
            scheduler.create_lease(
                name="refused",
                valid_from=tomorrow,
                valid_until=tomorrow + HOUR,
                component_names=["node-01"],
            )
        assert caught.value.status_code == 503
        assert caught.value.retryable
        omf_sfa.faults(unavailable=False)
        assert scheduler.list_leases() == []


def test_times_off_the_brokers_grid_are_refused_unless_the_adapter_widens_them(
    slots: Standin, tomorrow: datetime
) -> None:
    start = tomorrow + timedelta(minutes=5)
    end = tomorrow + timedelta(minutes=47)
    with slots.scheduler() as scheduler:
        with pytest.raises(SchedulerRejected) as caught:
            scheduler.create_lease(
                name="off-grid", valid_from=start, valid_until=end, component_names=["node-01"]
            )
        assert caught.value.status_code == 422
        assert "granularity" in caught.value.reason
    with slots.scheduler(granularity_s=600) as scheduler:
        lease = scheduler.create_lease(
            name="on-grid", valid_from=start, valid_until=end, component_names=["node-01"]
        )
        assert (lease.valid_from, lease.valid_until) == (
            tomorrow,
            tomorrow + timedelta(minutes=50),
        )
        moved = scheduler.move_lease(
            uuid=lease.uuid, valid_from=start + HOUR, valid_until=end + HOUR
        )
        assert moved.valid_from == tomorrow + HOUR


def test_a_clash_answered_as_an_empty_lease_is_a_conflict_and_the_debris_is_cancelled(
    zombie: Standin, tomorrow: datetime
) -> None:
    with zombie.scheduler() as scheduler:
        kept = scheduler.create_lease(
            name="kept",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-01"],
        )
        with pytest.raises(SchedulerConflict) as caught:
            scheduler.create_lease(
                name="zombie",
                valid_from=tomorrow,
                valid_until=tomorrow + HOUR,
                component_names=["node-01", "node-02"],
            )
        assert "no components" in caught.value.message
        debris = scheduler.get_lease(name="zombie")
        assert debris is not None
        assert debris.status is LeaseStatus.CANCELLED
        assert debris.component_names == ()
        assert scheduler.list_leases() == [kept]

        # omf_sfa answers a clashing move with a 400 that says so in words.
        other = scheduler.create_lease(
            name="other",
            valid_from=tomorrow + HOUR,
            valid_until=tomorrow + 2 * HOUR,
            component_names=["node-01"],
        )
        with pytest.raises(SchedulerConflict) as moved:
            scheduler.move_lease(
                uuid=other.uuid, valid_from=tomorrow, valid_until=tomorrow + 2 * HOUR
            )
        assert moved.value.status_code == 400
        assert moved.value.node_names == ("node-01",)


def test_a_lease_the_broker_made_with_only_some_nodes_is_cancelled_and_refused(
    standin: Standin, tomorrow: datetime
) -> None:
    with standin.scheduler() as scheduler:
        with pytest.raises(SchedulerRejected) as caught:
            scheduler.create_lease(
                name="partial",
                valid_from=tomorrow,
                valid_until=tomorrow + HOUR,
                component_names=["node-01", "node-99"],
            )
        assert "node-99" in caught.value.message
        partial = scheduler.get_lease(name="partial")
        assert partial is not None
        assert partial.component_names == ("node-01",)
        assert partial.status is LeaseStatus.CANCELLED
        # node-01 is free again.
        scheduler.create_lease(
            name="whole",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-01"],
        )


def test_a_lease_of_nodes_all_unknown_is_refused(standin: Standin, tomorrow: datetime) -> None:
    with standin.scheduler() as scheduler, pytest.raises(SchedulerError) as caught:
        scheduler.create_lease(
            name="ghosts",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-98", "node-99"],
        )
    assert not caught.value.retryable


def test_by_name_a_live_lease_comes_before_a_cancelled_one(
    standin: Standin, tomorrow: datetime
) -> None:
    with standin.scheduler() as scheduler:
        first = scheduler.create_lease(
            name="reservation-5",
            valid_from=tomorrow + 2 * HOUR,
            valid_until=tomorrow + 3 * HOUR,
            component_names=["node-16"],
        )
        scheduler.cancel_lease(uuid=first.uuid)
        retry = scheduler.create_lease(
            name="reservation-5",
            valid_from=tomorrow,
            valid_until=tomorrow + HOUR,
            component_names=["node-16"],
        )
        assert scheduler.get_lease(name="reservation-5") == retry


def test_clients_racing_for_one_slot_get_exactly_one_lease(
    omf_sfa: Standin, tomorrow: datetime
) -> None:
    outcomes: list[str] = []
    lock = threading.Lock()

    def book(k: int) -> None:
        with omf_sfa.scheduler() as scheduler:
            try:
                scheduler.create_lease(
                    name=f"racer-{k}",
                    valid_from=tomorrow,
                    valid_until=tomorrow + HOUR,
                    component_names=["node-24"],
                )
                outcome = "won"
            except SchedulerConflict:
                outcome = "lost"
            except SchedulerError as exc:
                outcome = type(exc).__name__
        with lock:
            outcomes.append(outcome)

    threads = [threading.Thread(target=book, args=(k,)) for k in range(12)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    assert sorted(outcomes) == ["lost"] * 11 + ["won"]


def test_naive_times_and_empty_leases_are_programming_errors(omf_sfa: Standin) -> None:
    naive = datetime(2030, 1, 1, 10, 0)
    aware = naive.replace(tzinfo=UTC)
    with omf_sfa.scheduler() as scheduler:
        with pytest.raises(ValueError, match="timezone-aware"):
            scheduler.create_lease(
                name="n", valid_from=naive, valid_until=aware, component_names=["node-01"]
            )
        with pytest.raises(ValueError, match="at least one component"):
            scheduler.create_lease(
                name="n", valid_from=aware, valid_until=aware + HOUR, component_names=[]
            )
        with pytest.raises(ValueError, match="before"):
            scheduler.move_lease(uuid="x", valid_from=aware, valid_until=aware)
