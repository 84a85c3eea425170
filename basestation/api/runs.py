"""``/api/v1/runs``: stage, inspect, withdraw runs and page through their samples."""

from __future__ import annotations

import io
import re
import time
from typing import Any

from flask import Blueprint, Response, current_app, jsonify, request, url_for
from flask.typing import ResponseReturnValue

from basestation.api.bodies import json_body
from basestation.api.errors import invalid_response
from basestation.contract import SAMPLE_FIELDS, CsvWriter
from basestation.cpu_slots import slot_released
from basestation.errors import RunNotFound
from basestation.program import FieldErrors
from basestation.runtime import get_runtime
from basestation.services import is_valid_run_id, run_stage, run_withdraw
from basestation.store import RUN_STATES, RUNNING, STAGED, RunRecord, RunStore, Sample, SampleStats

bp = Blueprint("runs", __name__)

DEFAULT_PAGE = 1000
MAX_PAGE = 5000
# A request for a running run's samples may wait this long for the next ones (long-poll):
# the portal's collector follows a run with one such request at a time, and each holds one
# HTTP thread of the agent while it waits.
MAX_WAIT_S = 30
# Waiting is only worth it while samples can still come.
_WAITABLE_STATES = (STAGED, RUNNING)
# The CSV page has the contract's columns, in its order.
SAMPLE_CSV_COLUMNS = SAMPLE_FIELDS
_UNSIGNED = re.compile(r"[0-9]{1,15}")
ENCODE_SLICE = 100


def _run_json(record: RunRecord, stats: SampleStats | None = None) -> dict[str, Any]:
    runtime = get_runtime()
    if stats is None:
        stats = runtime.store.sample_stats(record.id)
    agent, firmware = runtime.provenance_facts()
    recorded = record.provenance or {}
    return {
        **record.to_json_dict(stats),
        # The samples' ``track_m`` wraps at this length: whoever analyses them needs it.
        "rail_length_m": runtime.control.rail_length_m,
        # How the run is made: this agent and its robot's firmware as they are now, and what
        # the control loop recorded as the run started and ended (basestation/provenance.py).
        "provenance": {
            "agent": agent,
            "firmware": firmware,
            "started": recorded.get("started"),
            "ended": recorded.get("ended"),
        },
    }


@bp.get("/runs")
def list_runs() -> ResponseReturnValue:
    state = request.args.get("state")
    if state is not None and state not in RUN_STATES:
        return invalid_response({"state": [f"must be one of {', '.join(RUN_STATES)}"]})
    rows = get_runtime().store.list_runs(state=state)
    return jsonify({"runs": [_run_json(record, stats) for record, stats in rows]})


@bp.put("/runs/<run_id>")
def put_run(run_id: str) -> ResponseReturnValue:
    runtime = get_runtime()
    body = json_body()
    record, created = run_stage(
        store=runtime.store,
        manager=runtime.control,
        config=runtime.config,
        run_id=run_id,
        body=body,
        now_s=time.time(),
        disk=runtime.disk(),
    )
    response = jsonify(_run_json(record))
    if created:
        response.status_code = 201
        response.headers["Location"] = url_for(".get_run", run_id=record.id)
    return response


@bp.get("/runs/<run_id>")
def get_run(run_id: str) -> ResponseReturnValue:
    found = get_runtime().store.get_run_with_stats(run_id) if is_valid_run_id(run_id) else None
    if found is None:
        raise RunNotFound(run_id)
    return jsonify(_run_json(*found))


@bp.delete("/runs/<run_id>")
def delete_run(run_id: str) -> ResponseReturnValue:
    runtime = get_runtime()
    record = run_withdraw(
        store=runtime.store, manager=runtime.control, run_id=run_id, now_s=time.time()
    )
    return jsonify(_run_json(record))


@bp.get("/runs/<run_id>/samples")
def get_samples(run_id: str) -> ResponseReturnValue:
    store = get_runtime().store
    record = store.get_run(run_id) if is_valid_run_id(run_id) else None
    if record is None:
        raise RunNotFound(run_id)
    errors: FieldErrors = {}
    after_seq = _int_arg("after", 0, low=0, high=None, errors=errors)
    limit = _int_arg("limit", DEFAULT_PAGE, low=1, high=MAX_PAGE, errors=errors)
    wait_s = _int_arg("wait_s", 0, low=0, high=MAX_WAIT_S, errors=errors)
    if errors:
        return invalid_response(errors)
    record, samples = _samples_or_wait(store, record, after_seq, limit + 1, wait_s)
    more = len(samples) > limit
    samples = samples[:limit]  # one row more than asked tells whether another page follows
    # With an empty page last_seq stays at `after`, so `after=last_seq` always continues.
    last_seq = samples[-1].seq if samples else after_seq

    wants = request.accept_mimetypes.best_match(["application/json", "text/csv"])
    if wants == "text/csv":
        buffer = io.StringIO()
        writer = CsvWriter(buffer)
        writer.writerow(SAMPLE_CSV_COLUMNS)
        for sample in samples:
            writer.writerow(sample.values())
        response = Response(buffer.getvalue(), mimetype="text/csv")
        response.headers["X-Run-State"] = record.state
        response.headers["X-Last-Seq"] = str(last_seq)
        response.headers["X-More"] = "true" if more else "false"
    else:
        response = Response(
            _page_json(run_id, record.state, samples, last_seq, more),
            mimetype="application/json",
        )
    response.vary.add("Accept")
    return response


# How often a long-poll looks at the store again while it waits (see _samples_or_wait).
CROSS_PROCESS_LOOK_S = 0.05


def _samples_or_wait(
    store: RunStore, record: RunRecord, after_seq: int, limit: int, wait_s: int
) -> tuple[RunRecord, list[Sample]]:
    """The samples after ``after_seq``; if there are none yet and the run may still record
    some, wait up to ``wait_s`` for the store to commit the next ones (or the run's end), so
    a follower hears of a sample as soon as it is durable, without polling."""
    deadline = time.monotonic() + wait_s
    while True:
        # The version before looking: a commit after the look ends the wait below at once.
        version = store.version
        # The state before the samples: the writer commits a run's last samples before its
        # end, so a page that says "ended" holds every sample still to come.
        record = store.get_run(record.id) or record
        samples = store.samples_after(record.id, after_seq, limit)
        remaining_s = deadline - time.monotonic()
        if samples or record.state not in _WAITABLE_STATES or remaining_s <= 0:
            return record, samples
        # The store's writer may live in another process (the control loop's): its commits
        # wake no waiter here, so the wait is cut into short slices that look again.
        # Only waiting: another request may run meanwhile (basestation/cpu_slots.py).
        with slot_released():
            store.wait_changed(version, min(remaining_s, CROSS_PROCESS_LOOK_S))


def _page_json(run_id: str, state: str, samples: list[Sample], last_seq: int, more: bool) -> str:
    """The page as JSON, encoded a slice at a time.

    One ``json.dumps`` of 1000 samples holds the GIL for about 3.5 ms in C, without a
    chance for the control loop's thread to take it: under load that came straight out of
    the loop's timing. Slices of ENCODE_SLICE give the GIL a chance between them.
    """
    dumps = current_app.json.dumps
    head = dumps({"run_id": run_id, "state": state, "last_seq": last_seq, "more": more})
    parts = [
        dumps([s.to_json_dict() for s in samples[i : i + ENCODE_SLICE]])[1:-1]
        for i in range(0, len(samples), ENCODE_SLICE)
    ]
    return head[:-1] + ', "samples": [' + ",".join(parts) + "]}"


def _int_arg(name: str, default: int, *, low: int, high: int | None, errors: FieldErrors) -> int:
    raw = request.args.get(name)
    if raw is None:
        return default
    if not _UNSIGNED.fullmatch(raw):
        errors.setdefault(name, []).append("must be a non-negative integer")
        return default
    value = int(raw)
    if value < low or (high is not None and value > high):
        bound = f"between {low} and {high}" if high is not None else f"at least {low}"
        errors.setdefault(name, []).append(f"must be {bound}")
    return value
