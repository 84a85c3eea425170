"""The run store: one SQLite file (WAL) holding staged runs and every sample they produced.

Durability is the point of this module: the agent may be killed at any moment, and every
sample it acknowledged must still be there, exactly once, afterwards. Hence
``synchronous=FULL`` (a committed tick survives power loss, not only a process crash), one
transaction per tick batch, and ``(run_id, seq)`` as the samples' primary key.

Each thread gets its own connection: in WAL mode readers never block the writer, so an HTTP
thread paging through 5 000 samples does not delay the control loop's next commit.
Writers are serialised by SQLite itself (``BEGIN IMMEDIATE`` with a busy timeout), which
also makes every check-then-write below atomic.

One thing: the run store, and everything that reads or writes its file — staging, samples,
provenance, the usage log, purging, the backup's checks — kept together because its
durability rules (one transaction per batch, exactly-once sequence numbers) hold only if every
query obeys them in one place.
"""

from __future__ import annotations

import json
import logging
import re
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from basestation import contract
from basestation.contract import SAMPLE_FIELDS
from basestation.errors import RunConflict
from basestation.program import RunSpec, format_epoch

# The run states are the contract's (the portal maps their ends to its own states).
STAGED: Final = contract.AGENT_STAGED
RUNNING: Final = contract.AGENT_RUNNING
COMPLETED: Final = contract.AGENT_COMPLETED
CANCELLED: Final = contract.AGENT_CANCELLED
ABORTED: Final = contract.AGENT_ABORTED
INTERRUPTED: Final = contract.AGENT_INTERRUPTED
FAILED: Final = contract.AGENT_FAILED
RUN_STATES: Final = contract.AGENT_RUN_STATES
# States that hold the robot's time: new runs must not overlap them.
ACTIVE_STATES: Final = contract.AGENT_ACTIVE_STATES
END_STATES: Final = contract.AGENT_END_STATES
# The samples table's columns after run_id, in the contract's order (by name, never position).
_SAMPLE_COLUMNS_SQL: Final = ", ".join(SAMPLE_FIELDS)
_SAMPLE_PLACEHOLDERS: Final = ", ".join("?" for _ in SAMPLE_FIELDS)
_RUN_STATES_SQL: Final = ", ".join(f"'{state}'" for state in RUN_STATES)
_COLUMN_NAME: Final = re.compile(r"[a-z_]+")

logger = logging.getLogger(__name__)

# 2: manual_sessions and agent_state (created on the first start of v2)
# 3: the robot's position with each sample (fix, lat/lon, grid id, lap), added in place
# 4: runs.provenance: what the control loop recorded as each run started and ended
SCHEMA_VERSION = 4
# Columns added to ``samples`` after version 1, with their types: an older store gains them
# on open (nullable, so its existing samples simply have no position).
SAMPLE_POSITION_COLUMNS = {
    "fix_quality": "INTEGER",
    "lat_deg": "REAL",
    "lon_deg": "REAL",
    "grid_id": "TEXT",
    "lap": "INTEGER",
}
BUSY_TIMEOUT_MS = 5_000
# Retention deletes this many samples per transaction, so that the control loop's next
# commit never waits long for the write lock.
PURGE_BATCH_ROWS = 2_000

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS runs (
    id TEXT PRIMARY KEY,
    body TEXT NOT NULL,              -- canonical JSON of the staged body
    owner TEXT NOT NULL,
    title TEXT NOT NULL,
    start_at REAL NOT NULL,          -- epoch seconds, agent clock
    end_at REAL NOT NULL,
    state TEXT NOT NULL CHECK (state IN ({_RUN_STATES_SQL})),
    reason TEXT,
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL,
    started_at REAL,
    ended_at REAL,
    provenance TEXT                  -- JSON: what the loop recorded at start and end
);
CREATE INDEX IF NOT EXISTS runs_state_start ON runs (state, start_at);
CREATE TABLE IF NOT EXISTS samples (
    run_id TEXT NOT NULL REFERENCES runs (id),
    seq INTEGER NOT NULL,
    t REAL NOT NULL,
    segment INTEGER,
    commanded_velocity_mps REAL NOT NULL,
    velocity_mps REAL NOT NULL,
    direction TEXT NOT NULL,
    battery_v REAL NOT NULL,
    track_m REAL NOT NULL,
    fix_quality INTEGER,             -- 0 none, 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float
    lat_deg REAL,
    lon_deg REAL,
    grid_id TEXT,                    -- the thesis grid (A1 …), None without a position
    lap INTEGER,                     -- whole laps since the run started (negative: ccw)
    PRIMARY KEY (run_id, seq)
) WITHOUT ROWID;
-- Admins driving the robot by hand (POST /control), for the daily usage log.
CREATE TABLE IF NOT EXISTS manual_sessions (
    id INTEGER PRIMARY KEY,
    user TEXT NOT NULL,
    started_at REAL NOT NULL,
    -- While the session lasts: the expiry of its last command (the robot is stopped by then
    -- whatever happens to the agent), so a crash leaves an upper bound, never an open end.
    ended_at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS manual_sessions_started ON manual_sessions (started_at);
-- Small pieces of agent state that must survive a restart (the latched e-stop).
CREATE TABLE IF NOT EXISTS agent_state (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""


@dataclass(frozen=True)
class Sample:
    seq: int
    t: float  # epoch seconds, agent clock
    segment: int | None  # None once the program is over (robot braking)
    commanded_velocity_mps: float
    velocity_mps: float
    direction: str
    battery_v: float
    track_m: float
    fix_quality: int | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    grid_id: str | None = None
    lap: int | None = None

    def to_json_dict(self) -> dict[str, Any]:
        """The sample as the agent's API sends it: the contract's columns, by name."""
        return {name: getattr(self, name) for name in SAMPLE_FIELDS}

    def values(self) -> tuple[Any, ...]:
        return tuple(getattr(self, name) for name in SAMPLE_FIELDS)


@dataclass(frozen=True)
class SampleStats:
    count: int
    first_seq: int | None
    last_seq: int | None


@dataclass(frozen=True)
class RunRecord:
    id: str
    spec: RunSpec
    body: str
    state: str
    reason: str | None
    created_at_s: float
    updated_at_s: float
    started_at_s: float | None
    ended_at_s: float | None
    # What the control loop recorded at the run's start and end ({"started", "ended"}).
    provenance: dict[str, Any] | None = None

    def to_json_dict(self, stats: SampleStats) -> dict[str, Any]:
        spec = self.spec.to_json_dict()
        return {
            "id": self.id,
            "owner": spec["owner"],
            "title": spec["title"],
            "state": self.state,
            "reason": self.reason,
            "start_at": spec["start_at"],
            "end_at": spec["end_at"],
            "segments": spec["segments"],
            "limits": spec["limits"],
            "sample_count": stats.count,
            "first_seq": stats.first_seq,
            "last_seq": stats.last_seq,
            "created_at": format_epoch(self.created_at_s),
            "updated_at": format_epoch(self.updated_at_s),
            "started_at": format_epoch(self.started_at_s),
            "ended_at": format_epoch(self.ended_at_s),
        }


@dataclass(frozen=True)
class UsageEntry:
    """One line of the daily usage log: who had the robot, from when to when."""

    kind: str  # "run" | "manual"
    user: str
    title: str
    start_s: float
    end_s: float | None  # None while the run is still running
    run_id: str | None
    state: str | None  # the run's state; None for manual control

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "user": self.user,
            "title": self.title,
            "start": format_epoch(self.start_s),
            "end": format_epoch(self.end_s),
            "run_id": self.run_id,
            "state": self.state,
        }


@dataclass(frozen=True)
class PurgeResult:
    runs: int = 0
    samples: int = 0
    manual_sessions: int = 0


class StoreClosed(Exception):
    pass


class RunStore:
    def __init__(self, path: Path, *, durable: bool = True) -> None:
        """``durable=False``: commits are not flushed to disk (``synchronous=OFF``), for a
        scratch store that lives no longer than its process (a dry run's)."""
        self.path = path
        self._durable = durable
        path.parent.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()
        # Each connection with the thread it belongs to (see ``close``).
        self._connections: list[tuple[threading.Thread, sqlite3.Connection]] = []
        self._connections_lock = threading.Lock()
        self._closed = False
        # Bumped (and waiters woken) after every commit of samples or of a run's state:
        # a reader waiting for a run's next samples wakes as soon as they are durable.
        self._changed = threading.Condition()
        self._version = 0
        self.waiting = 0  # readers waiting for a change now
        conn = self._conn()
        # WAL is a property of the file; set once here, every later connection inherits it.
        mode = conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            raise RuntimeError(f"{path}: SQLite refused WAL mode (got {mode!r})")
        conn.executescript(f"BEGIN IMMEDIATE; {_SCHEMA} COMMIT;")
        present = {row["name"] for row in conn.execute("PRAGMA table_info(samples)")}
        missing = [
            f"ALTER TABLE samples ADD COLUMN {name} {kind};"
            for name, kind in SAMPLE_POSITION_COLUMNS.items()
            if name not in present
        ]
        run_columns = {row["name"] for row in conn.execute("PRAGMA table_info(runs)")}
        if "provenance" not in run_columns:
            missing.append("ALTER TABLE runs ADD COLUMN provenance TEXT;")
        conn.executescript(
            f"BEGIN IMMEDIATE; {' '.join(missing)} PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
        )

    # -- connections and transactions ------------------------------------------------------

    def _conn(self) -> sqlite3.Connection:
        conn: sqlite3.Connection | None = getattr(self._local, "conn", None)
        if self._closed:
            if conn is not None:  # this thread's own, left open by close(): closed here
                self._local.conn = None
                conn.close()
            raise StoreClosed(f"run store {self.path} is closed")
        if conn is None:
            # isolation_level=None: we issue BEGIN/COMMIT ourselves, so a transaction is
            # exactly as wide as the code below says. check_same_thread=False only so that
            # close() can close the connections of threads that have ended.
            conn = sqlite3.connect(
                self.path, isolation_level=None, check_same_thread=False, timeout=10.0
            )
            conn.row_factory = sqlite3.Row
            conn.execute("PRAGMA synchronous=FULL" if self._durable else "PRAGMA synchronous=OFF")
            conn.execute("PRAGMA foreign_keys=ON")
            conn.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
            self._local.conn = conn
            with self._connections_lock:
                self._connections.append((threading.current_thread(), conn))
        return conn

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        conn = self._conn()
        # IMMEDIATE takes the write lock up front: the checks made inside the block still
        # hold when its writes commit.
        conn.execute("BEGIN IMMEDIATE")
        try:
            yield conn
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        conn.execute("COMMIT")

    @contextmanager
    def _read(self) -> Iterator[sqlite3.Connection]:
        """A consistent snapshot across several SELECTs (a page and its ``more`` flag)."""
        conn = self._conn()
        conn.execute("BEGIN")
        try:
            yield conn
        finally:
            conn.execute("COMMIT")

    def close(self) -> None:
        """Refuse every later call (``StoreClosed``) and wake the waiters.

        Closes this thread's connection and those of threads that have ended; a live thread's
        is closed by that thread, at its next call (or when the thread ends). Closing a
        connection that another thread is stepping a statement on frees what that thread is
        still using: an HTTP thread mid-query at shutdown took the whole process down with a
        segmentation fault."""
        self._closed = True
        me = threading.current_thread()
        with self._connections_lock:
            connections, self._connections = self._connections, []
        for owner, conn in connections:
            if owner is me or not owner.is_alive():
                conn.close()
        if getattr(self._local, "conn", None) is not None:
            self._local.conn = None
        self._signal()

    # -- waiting for changes -----------------------------------------------------------------

    @property
    def version(self) -> int:
        """Moves on after every committed change of samples or run state (see ``wait_changed``)."""
        return self._version

    def _signal(self) -> None:
        with self._changed:
            self._version += 1
            self._changed.notify_all()

    def wait_changed(self, version: int, timeout_s: float) -> bool:
        """Wait until something was committed after ``version`` was read (True), the store
        closed (True) or ``timeout_s`` passed (False). Read ``version`` before looking, then
        wait: a commit in between is never missed."""
        with self._changed:
            self.waiting += 1
            try:
                return self._changed.wait_for(
                    lambda: self._version != version or self._closed, timeout=max(0.0, timeout_s)
                )
            finally:
                self.waiting -= 1

    # -- runs --------------------------------------------------------------------------------

    def mark_interrupted(self, *, now_s: float, reason: str) -> list[str]:
        """Move every run left ``running`` (the agent died under it) to ``interrupted``."""
        with self._write() as tx:
            ids = [r["id"] for r in tx.execute("SELECT id FROM runs WHERE state = ?", (RUNNING,))]
            tx.execute(
                "UPDATE runs SET state = ?, reason = ?, updated_at = ?, ended_at = ? "
                "WHERE state = ?",
                (INTERRUPTED, reason, now_s, now_s, RUNNING),
            )
        for run_id in ids:
            _log_state_change(run_id, RUNNING, INTERRUPTED, reason)
        return ids

    def stage_run(
        self,
        run_id: str,
        spec: RunSpec,
        *,
        now_s: float,
        admit: Callable[[RunSpec], None],
    ) -> tuple[RunRecord, bool]:
        """Store a new run, or recognise an identical one; returns (record, created).

        ``admit`` runs inside the write transaction, only for a new run, and raises to
        refuse it (clock- and agent-dependent checks that a repeat must not re-run).
        Raises :class:`RunConflict` for a different body under the same id, or a window
        overlapping another staged or running run.
        """
        body = spec.canonical_json()
        with self._write() as tx:
            row = tx.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
            if row is not None:
                if row["body"] == body:
                    return _record(row), False
                raise RunConflict(
                    "body_differs", f"run {run_id} is already staged with a different body"
                )
            admit(spec)
            # Half-open windows [start, end): back-to-back runs do not overlap.
            overlap, params = overlap_condition(
                "start_at", "end_at", spec.start_at_s, spec.end_at_s
            )
            other = tx.execute(
                "SELECT id, start_at, end_at FROM runs "
                f"WHERE state IN ('staged', 'running') AND {overlap} "
                "ORDER BY start_at LIMIT 1",
                params,
            ).fetchone()
            if other is not None:
                raise RunConflict(
                    "window_overlaps",
                    f"the window overlaps run {other['id']} "
                    f"({format_epoch(other['start_at'])} to {format_epoch(other['end_at'])})",
                )
            tx.execute(
                "INSERT INTO runs (id, body, owner, title, start_at, end_at, state, reason, "
                "created_at, updated_at) VALUES (?, ?, ?, ?, ?, ?, ?, NULL, ?, ?)",
                (
                    run_id,
                    body,
                    spec.owner,
                    spec.title,
                    spec.start_at_s,
                    spec.end_at_s,
                    STAGED,
                    now_s,
                    now_s,
                ),
            )
            row = tx.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
        _log_state_change(run_id, None, STAGED, f"{spec.start_at_s - now_s:+.1f} s to start")
        return _record(row), True

    def transition(
        self,
        run_id: str,
        *,
        from_states: Sequence[str],
        to_state: str,
        reason: str | None,
        now_s: float,
    ) -> bool:
        """Compare-and-set the state; False when the run is not in one of ``from_states``.

        ``started_at`` is set on entering ``running``, ``ended_at`` on entering an end state.
        """
        if to_state not in RUN_STATES:
            raise ValueError(f"unknown run state {to_state!r}")
        started_at_s = now_s if to_state == RUNNING else None
        ended_at_s = now_s if to_state in END_STATES else None
        with self._write() as tx:
            row = tx.execute("SELECT state FROM runs WHERE id = ?", (run_id,)).fetchone()
            if row is None or row["state"] not in from_states:
                return False
            tx.execute(
                "UPDATE runs SET state = ?, reason = ?, updated_at = ?, "
                "started_at = COALESCE(?, started_at), ended_at = COALESCE(?, ended_at) "
                "WHERE id = ?",
                (to_state, reason, now_s, started_at_s, ended_at_s, run_id),
            )
        self._signal()
        _log_state_change(run_id, row["state"], to_state, reason)
        return True

    def run_provenance_set(self, run_id: str, key: str, value: dict[str, Any]) -> bool:
        """Record ``value`` as the run's provenance ``key`` ("started", "ended"); False when
        the run is unknown. Whatever else was recorded is kept."""
        with self._write() as tx:
            row = tx.execute("SELECT provenance FROM runs WHERE id = ?", (run_id,)).fetchone()
            if row is None:
                return False
            recorded = _provenance(row["provenance"]) or {}
            recorded[key] = value
            tx.execute(
                "UPDATE runs SET provenance = ? WHERE id = ?",
                (json.dumps(recorded, separators=(",", ":")), run_id),
            )
        return True

    def get_run(self, run_id: str) -> RunRecord | None:
        row = self._conn().execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
        return None if row is None else _record(row)

    def get_run_with_stats(self, run_id: str) -> tuple[RunRecord, SampleStats] | None:
        with self._read() as conn:
            row = conn.execute(_RUN_WITH_STATS + "WHERE r.id = ?", (run_id,)).fetchone()
        return None if row is None else (_record(row), _stats(row))

    def list_runs(
        self, *, state: str | None = None, limit: int = 1000
    ) -> list[tuple[RunRecord, SampleStats]]:
        """Newest first (by start time)."""
        with self._read() as conn:
            rows = conn.execute(
                _RUN_WITH_STATS + "WHERE (? IS NULL OR r.state = ?) "
                "ORDER BY r.start_at DESC, r.id LIMIT ?",
                (state, state, limit),
            ).fetchall()
        return [(_record(row), _stats(row)) for row in rows]

    def staged_runs(self) -> list[RunRecord]:
        """Oldest first (by start time): the manager's schedule."""
        rows = self._conn().execute(
            "SELECT * FROM runs WHERE state = 'staged' ORDER BY start_at, id"
        )
        return [_record(row) for row in rows]

    def running_run_id(self) -> str | None:
        row = self._conn().execute("SELECT id FROM runs WHERE state = 'running' LIMIT 1").fetchone()
        return None if row is None else str(row["id"])

    def active_seconds_ahead(self, now_s: float) -> float:
        """Seconds of staged or running windows still ahead of ``now_s`` (disk planning)."""
        row = (
            self._conn()
            .execute(
                "SELECT COALESCE(SUM(MAX(end_at - MAX(start_at, ?), 0)), 0) AS ahead "
                "FROM runs WHERE state IN ('staged', 'running')",
                (now_s,),
            )
            .fetchone()
        )
        return float(row["ahead"])

    # -- e-stop latch ------------------------------------------------------------------------

    def get_estop(self) -> tuple[float, str] | None:
        """(since, reason) of the latched e-stop, or None when released."""
        row = self._conn().execute("SELECT value FROM agent_state WHERE key = 'estop'").fetchone()
        if row is None:
            return None
        value = json.loads(row["value"])
        return float(value["since_s"]), str(value["reason"])

    def set_estop(self, *, since_s: float, reason: str) -> None:
        value = json.dumps({"since_s": since_s, "reason": reason})
        with self._write() as tx:
            tx.execute(
                "INSERT INTO agent_state (key, value) VALUES ('estop', ?) "
                "ON CONFLICT (key) DO NOTHING",
                (value,),
            )

    def clear_estop(self) -> None:
        with self._write() as tx:
            tx.execute("DELETE FROM agent_state WHERE key = 'estop'")

    # -- manual control sessions and the usage log ---------------------------------------------

    def manual_session_open(self, *, user: str, started_at_s: float, until_s: float) -> int:
        with self._write() as tx:
            cursor = tx.execute(
                "INSERT INTO manual_sessions (user, started_at, ended_at) VALUES (?, ?, ?)",
                (user, started_at_s, until_s),
            )
        assert cursor.lastrowid is not None
        return cursor.lastrowid

    def manual_session_extend(self, session_id: int, *, until_s: float) -> None:
        with self._write() as tx:
            tx.execute(
                "UPDATE manual_sessions SET ended_at = MAX(ended_at, ?) WHERE id = ?",
                (until_s, session_id),
            )

    def manual_session_end(self, session_id: int, *, ended_at_s: float) -> None:
        """End a session early (never later than its last command's expiry)."""
        with self._write() as tx:
            tx.execute(
                "UPDATE manual_sessions SET ended_at = MIN(ended_at, MAX(started_at, ?)) "
                "WHERE id = ?",
                (ended_at_s, session_id),
            )

    def usage_between(self, start_s: float, end_s: float) -> list[UsageEntry]:
        """Runs that moved the robot and manual sessions overlapping ``[start_s, end_s)``,
        ordered by start.

        Half-open like every period: one that ended exactly at ``start_s`` belongs to the
        window before, one that starts exactly at ``end_s`` to the next. A run still going
        (no ``ended_at`` yet) reaches to the end of any window after its start.
        """
        run_overlap, run_params = overlap_condition(
            "started_at", "ended_at", start_s, end_s, open_end=True
        )
        session_overlap, session_params = overlap_condition(
            "started_at", "ended_at", start_s, end_s
        )
        with self._read() as conn:
            runs = conn.execute(
                "SELECT id, owner, title, state, started_at, ended_at FROM runs "
                f"WHERE started_at IS NOT NULL AND {run_overlap}",
                run_params,
            ).fetchall()
            sessions = conn.execute(
                f"SELECT user, started_at, ended_at FROM manual_sessions WHERE {session_overlap}",
                session_params,
            ).fetchall()
        entries = [
            UsageEntry(
                kind="run",
                user=row["owner"],
                title=row["title"],
                start_s=row["started_at"],
                end_s=row["ended_at"],
                run_id=row["id"],
                state=row["state"],
            )
            for row in runs
        ]
        entries += [
            UsageEntry(
                kind="manual",
                user=row["user"],
                title="manual control",
                start_s=row["started_at"],
                end_s=row["ended_at"],
                run_id=None,
                state=None,
            )
            for row in sessions
        ]
        entries.sort(key=lambda e: (e.start_s, e.kind, e.run_id or ""))
        return entries

    # -- housekeeping --------------------------------------------------------------------------

    def purge_ended_before(
        self, cutoff_s: float, *, batch_rows: int = PURGE_BATCH_ROWS, pause_s: float = 0.0
    ) -> PurgeResult:
        """Delete runs that ended before ``cutoff_s``, with their samples, and manual
        sessions that ended before it. Staged and running runs are never touched.

        Samples go in batches of ``batch_rows``, one transaction each, ``pause_s`` apart
        (the control loop's commits get the write lock in between); a run's row goes last,
        so an interrupted purge leaves a run with fewer samples, never samples without a run.
        """
        runs = samples = 0
        end_states = ", ".join(f"'{state}'" for state in END_STATES)
        run_ids = [
            row["id"]
            for row in self._conn().execute(
                f"SELECT id FROM runs WHERE state IN ({end_states}) "
                "AND COALESCE(ended_at, updated_at) < ? ORDER BY ended_at",
                (cutoff_s,),
            )
        ]
        for run_id in run_ids:
            while True:
                with self._write() as tx:
                    deleted = tx.execute(
                        "DELETE FROM samples WHERE run_id = ? AND seq IN "
                        "(SELECT seq FROM samples WHERE run_id = ? ORDER BY seq LIMIT ?)",
                        (run_id, run_id, batch_rows),
                    ).rowcount
                samples += deleted
                if deleted < batch_rows:
                    break
                if pause_s > 0:
                    time.sleep(pause_s)
            with self._write() as tx:
                runs += tx.execute(
                    f"DELETE FROM runs WHERE id = ? AND state IN ({end_states}) "
                    "AND NOT EXISTS (SELECT 1 FROM samples WHERE run_id = ?)",
                    (run_id, run_id),
                ).rowcount
        with self._write() as tx:
            sessions = tx.execute(
                "DELETE FROM manual_sessions WHERE ended_at < ?", (cutoff_s,)
            ).rowcount
        if runs or sessions:
            logger.info(
                "retention: deleted %d runs (%d samples) and %d manual sessions that ended "
                "before %s",
                runs,
                samples,
                sessions,
                format_epoch(cutoff_s),
            )
        return PurgeResult(runs=runs, samples=samples, manual_sessions=sessions)

    def checkpoint(self) -> None:
        """Copy the WAL back into the database file without blocking writers (PASSIVE), so
        that the automatic checkpoint never falls to the control loop's commit."""
        self._conn().execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()

    # -- samples -----------------------------------------------------------------------------

    def append_samples(self, run_id: str, samples: Sequence[Sample]) -> bool:
        """Store one tick batch in one transaction, only while the run is ``running``.

        Returns False (and stores nothing) once the run has left ``running`` — e.g. an
        abort committed by an HTTP thread a moment ago — so no sample ever lands in a
        run the portal already considers ended.
        """
        with self._write() as tx:
            row = tx.execute("SELECT state FROM runs WHERE id = ?", (run_id,)).fetchone()
            if row is None or row["state"] != RUNNING:
                return False
            tx.executemany(
                f"INSERT INTO samples (run_id, {_SAMPLE_COLUMNS_SQL}) "
                f"VALUES (?, {_SAMPLE_PLACEHOLDERS})",
                [(run_id, *s.values()) for s in samples],
            )
        self._signal()
        return True

    def samples_after(self, run_id: str, after_seq: int, limit: int) -> list[Sample]:
        """Up to ``limit`` samples with ``seq > after_seq``, ordered by seq."""
        rows = self._conn().execute(
            f"SELECT {_SAMPLE_COLUMNS_SQL} FROM samples "
            "WHERE run_id = ? AND seq > ? ORDER BY seq LIMIT ?",
            (run_id, after_seq, limit),
        )
        return [_sample(row) for row in rows]

    def sample_stats(self, run_id: str) -> SampleStats:
        row = (
            self._conn()
            .execute(
                "SELECT COUNT(*) AS sample_count, MIN(seq) AS first_seq, MAX(seq) AS last_seq "
                "FROM samples WHERE run_id = ?",
                (run_id,),
            )
            .fetchone()
        )
        return _stats(row)


def overlap_condition(
    start_column: str, end_column: str, start_s: float, end_s: float, *, open_end: bool = False
) -> tuple[str, tuple[float, float]]:
    """The SQL condition "the row's ``[start_column, end_column)`` shares an instant with
    ``[start_s, end_s)``", and its parameters in order.

    The agent's one spelling of the half-open rule every period follows (the portal's is
    ``bookings/periods.py``): back to back is no overlap. With ``open_end`` a NULL end is a
    period that has not ended yet. The columns are this module's own names, never input.
    """
    start, end = _column_name(start_column), _column_name(end_column)
    ends_after = f"{end} > ?"
    if open_end:
        ends_after = f"({end} IS NULL OR {ends_after})"
    return f"({start} < ? AND {ends_after})", (end_s, start_s)


def _column_name(name: str) -> str:
    """``name``, checked to be a plain column name (``ValueError`` otherwise)."""
    if not _COLUMN_NAME.fullmatch(name):
        raise ValueError(f"not a column name: {name!r}")
    return name


# -- a store's file as a whole (basestation.backup) ------------------------------------------


def file_check(conn: sqlite3.Connection) -> tuple[str, set[str], int]:
    """What SQLite's integrity check says of the file ``conn`` opened (``"ok"`` or what is
    wrong), the names of its tables, and its store version (``user_version``)."""
    integrity = conn.execute("PRAGMA integrity_check").fetchone()[0]
    tables = {row[0] for row in conn.execute("SELECT name FROM sqlite_master")}
    version = conn.execute("PRAGMA user_version").fetchone()[0]
    return str(integrity), tables, int(version)


def file_counts(conn: sqlite3.Connection) -> tuple[int, int]:
    """How many runs and how many samples the file ``conn`` opened holds."""
    runs = conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
    samples = conn.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
    return int(runs), int(samples)


def file_standalone(conn: sqlite3.Connection) -> None:
    """Make the file ``conn`` opened a single file, with no WAL beside it (the agent sets WAL
    again when it opens the file)."""
    conn.execute("PRAGMA journal_mode=DELETE")


_RUN_WITH_STATS = (
    "SELECT r.*, "
    "(SELECT COUNT(*) FROM samples s WHERE s.run_id = r.id) AS sample_count, "
    "(SELECT MIN(seq) FROM samples s WHERE s.run_id = r.id) AS first_seq, "
    "(SELECT MAX(seq) FROM samples s WHERE s.run_id = r.id) AS last_seq "
    "FROM runs r "
)


def _log_state_change(
    run_id: str, from_state: str | None, to_state: str, reason: str | None
) -> None:
    # Logged here, where the change commits, so every change gets exactly one line whoever
    # made it (control loop, HTTP thread, startup recovery).
    logger.info("run %s: %s -> %s (%s)", run_id, from_state or "new", to_state, reason or "")


def _record(row: sqlite3.Row) -> RunRecord:
    return RunRecord(
        id=row["id"],
        spec=RunSpec.from_canonical_json(row["body"]),
        body=row["body"],
        state=row["state"],
        reason=row["reason"],
        created_at_s=row["created_at"],
        updated_at_s=row["updated_at"],
        started_at_s=row["started_at"],
        ended_at_s=row["ended_at"],
        provenance=_provenance(row["provenance"]),
    )


def _provenance(text: str | None) -> dict[str, Any] | None:
    if not text:
        return None
    try:
        value = json.loads(text)
    except ValueError:
        logger.warning("unreadable run provenance %r", text[:80])
        return None
    return value if isinstance(value, dict) else None


def _stats(row: sqlite3.Row) -> SampleStats:
    return SampleStats(
        count=int(row["sample_count"]), first_seq=row["first_seq"], last_seq=row["last_seq"]
    )


def _sample(row: sqlite3.Row) -> Sample:
    return Sample(**{name: row[name] for name in SAMPLE_FIELDS})
