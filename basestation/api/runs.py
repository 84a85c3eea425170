"""``/api/v1/runs``: stage, inspect, withdraw runs and page through their samples."""

from __future__ import annotations

import csv
import io
import json
import re
import time
from typing import Any

from flask import Blueprint, Response, jsonify, request, url_for
from flask.typing import ResponseReturnValue
from werkzeug.exceptions import UnsupportedMediaType

from basestation.api.errors import invalid_response
from basestation.errors import RunNotFound
from basestation.program import FieldErrors, InvalidRunBody
from basestation.runtime import get_runtime
from basestation.services import is_valid_run_id, run_stage, run_withdraw
from basestation.store import RUN_STATES, RunRecord, SampleStats

bp = Blueprint("runs", __name__)

DEFAULT_PAGE = 1000
MAX_PAGE = 5000
SAMPLE_CSV_COLUMNS = (
    "seq",
    "t",
    "segment",
    "commanded_velocity_mps",
    "velocity_mps",
    "direction",
    "battery_v",
    "track_m",
)
_UNSIGNED = re.compile(r"[0-9]{1,15}")


def _run_json(record: RunRecord, stats: SampleStats | None = None) -> dict[str, Any]:
    if stats is None:
        stats = get_runtime().store.sample_stats(record.id)
    return record.to_json_dict(stats)


@bp.get("/runs")
def list_runs() -> ResponseReturnValue:
    state = request.args.get("state")
    if state is not None and state not in RUN_STATES:
        return invalid_response({"state": [f"must be one of {', '.join(RUN_STATES)}"]})
    rows = get_runtime().store.list_runs(state=state)
    return jsonify({"runs": [record.to_json_dict(stats) for record, stats in rows]})


@bp.put("/runs/<run_id>")
def put_run(run_id: str) -> ResponseReturnValue:
    runtime = get_runtime()
    if not request.is_json:
        raise UnsupportedMediaType("Send the run as JSON (Content-Type: application/json).")
    body = _decode_json(request.get_data(cache=False))
    record, created = run_stage(
        store=runtime.store,
        manager=runtime.manager,
        config=runtime.config,
        run_id=run_id,
        body=body,
        now_s=time.time(),
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
    return jsonify(found[0].to_json_dict(found[1]))


@bp.delete("/runs/<run_id>")
def delete_run(run_id: str) -> ResponseReturnValue:
    runtime = get_runtime()
    record = run_withdraw(
        store=runtime.store, manager=runtime.manager, run_id=run_id, now_s=time.time()
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
    if errors:
        return invalid_response(errors)
    # One row more than asked tells whether another page follows.
    samples = store.samples_after(run_id, after_seq, limit + 1)
    more = len(samples) > limit
    samples = samples[:limit]
    # With an empty page last_seq stays at `after`, so `after=last_seq` always continues.
    last_seq = samples[-1].seq if samples else after_seq

    wants = request.accept_mimetypes.best_match(["application/json", "text/csv"])
    if wants == "text/csv":
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(SAMPLE_CSV_COLUMNS)
        for sample in samples:
            row = sample.to_json_dict()
            writer.writerow([row[column] for column in SAMPLE_CSV_COLUMNS])
        response = Response(buffer.getvalue(), mimetype="text/csv")
        response.headers["X-Run-State"] = record.state
        response.headers["X-Last-Seq"] = str(last_seq)
        response.headers["X-More"] = "true" if more else "false"
    else:
        response = jsonify(
            {
                "run_id": run_id,
                "state": record.state,
                "samples": [sample.to_json_dict() for sample in samples],
                "last_seq": last_seq,
                "more": more,
            }
        )
    response.vary.add("Accept")
    return response


def _decode_json(data: bytes) -> object:
    def reject_constant(name: str) -> object:
        raise ValueError(f"{name} is not a JSON number")

    try:
        return json.loads(data.decode("utf-8"), parse_constant=reject_constant)
    except UnicodeDecodeError:
        raise InvalidRunBody({"body": ["must be UTF-8 encoded JSON"]}) from None
    except RecursionError:
        raise InvalidRunBody({"body": ["is nested too deeply"]}) from None
    except ValueError as exc:  # JSONDecodeError is a ValueError
        raise InvalidRunBody({"body": [f"is not valid JSON: {exc}"]}) from None


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
