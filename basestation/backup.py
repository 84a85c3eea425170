"""``python -m basestation.backup``: back up the agent's run store while it runs, restore it
into a stopped agent.

- ``backup DEST``: SQLite's online backup API copies the store (``AGENT_DATA_DIR``) into
  ``DEST`` as one consistent snapshot, while the agent goes on recording: in WAL mode the
  copy reads a snapshot and never blocks the control loop's commits. ``DEST`` is a single
  self-contained file (no ``-wal``), checked before it is put in place.
- ``restore SOURCE``: only while no agent serves the data directory (the serving agent holds
  ``agent.lock`` there; stop it first: ``systemctl stop amazing-agent``). The backup is
  checked first; the current store, with its WAL, is moved aside (never deleted) as
  ``runs.sqlite3.replaced-<time>``; then the backup is copied in. At its next start the
  agent marks a run that was running when the backup was taken as ``interrupted``, keeping
  its samples.

Exit codes: 0 done, 1 refused (the reason on standard error), 2 usage.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import os
import sqlite3
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from basestation.config import STORE_FILE_NAME, data_dir_from_env
from basestation.store import SCHEMA_VERSION, file_check, file_counts, file_standalone

LOCK_FILE_NAME = "agent.lock"
_STORE_TABLES = {"runs", "samples", "manual_sessions", "agent_state"}


class BackupError(Exception):
    """The backup or restore was refused; nothing was changed."""


class AgentRunning(BackupError):
    pass


@dataclass(frozen=True)
class StoreSummary:
    runs: int
    samples: int


@contextlib.contextmanager
def data_dir_lock(data_dir: Path) -> Iterator[IO[str]]:
    """Hold the data directory for as long as the block runs: the serving agent holds it for
    its life, a restore for its length. Raises :class:`AgentRunning` when another holds it."""
    data_dir.mkdir(parents=True, exist_ok=True)
    with (data_dir / LOCK_FILE_NAME).open("a+") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.seek(0)
            holder = lock.read().strip() or "another process"
            raise AgentRunning(
                f"an agent is using {data_dir} (pid {holder}): stop it first"
            ) from None
        lock.seek(0)
        lock.truncate()
        lock.write(str(os.getpid()))
        lock.flush()
        try:
            yield lock
        finally:
            lock.seek(0)
            lock.truncate()
            fcntl.flock(lock, fcntl.LOCK_UN)


def _summary(conn: sqlite3.Connection, what: Path) -> StoreSummary:
    """Check ``conn`` is a whole agent store; its run and sample counts."""
    try:
        integrity, tables, version = file_check(conn)
    except sqlite3.DatabaseError as exc:
        raise BackupError(f"{what} is not an SQLite database: {exc}") from None
    if integrity != "ok":
        raise BackupError(f"{what} fails SQLite's integrity check: {integrity}")
    if not tables >= _STORE_TABLES:
        raise BackupError(f"{what} is not an agent's run store (tables {sorted(tables)})")
    if version > SCHEMA_VERSION:
        raise BackupError(
            f"{what} is of a newer agent (store version {version}, this one reads up to "
            f"{SCHEMA_VERSION}): restore it with that version"
        )
    runs, samples = file_counts(conn)
    return StoreSummary(runs=runs, samples=samples)


def _copy(source: sqlite3.Connection, target_path: Path) -> StoreSummary:
    """Copy ``source`` into a new single file at ``target_path`` (written aside, checked,
    synced, then renamed into place: a crash leaves no half file under that name)."""
    partial = target_path.with_name(target_path.name + ".partial")
    partial.unlink(missing_ok=True)
    target = sqlite3.connect(partial)
    try:
        # One step (pages=-1): one read snapshot of the source, whatever commits meanwhile.
        source.backup(target)
        file_standalone(target)
        summary = _summary(target, target_path)
    except BaseException:
        target.close()
        partial.unlink(missing_ok=True)
        raise
    target.close()
    with partial.open("rb") as written:
        os.fsync(written.fileno())
    os.replace(partial, target_path)
    return summary


def store_backup(data_dir: Path, dest: Path) -> StoreSummary:
    """Back up the store in ``data_dir`` to ``dest`` (a new file), while the agent runs."""
    store = data_dir / STORE_FILE_NAME
    if not store.is_file():
        raise BackupError(f"no run store at {store}")
    if dest.exists():
        raise BackupError(f"{dest} exists: give a new file name")
    if not dest.parent.is_dir():
        raise BackupError(f"{dest.parent} is not a directory")
    source = sqlite3.connect(store, timeout=10.0)
    try:
        return _copy(source, dest)
    finally:
        source.close()


def store_restore(data_dir: Path, source_path: Path) -> tuple[StoreSummary, Path | None]:
    """Replace the store in ``data_dir`` with the backup at ``source_path``, while no agent
    runs there. Returns the restored store's counts and where the replaced store went."""
    if not source_path.is_file():
        raise BackupError(f"no backup at {source_path}")
    with data_dir_lock(data_dir):
        source = sqlite3.connect(f"file:{source_path}?mode=ro", uri=True)
        try:
            _summary(source, source_path)
            store = data_dir / STORE_FILE_NAME
            moved: Path | None = None
            if store.exists():
                stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
                moved = store.with_name(f"{store.name}.replaced-{stamp}")
                # The store and its WAL move together: under the new name they are still one
                # database, whatever the WAL held that was not yet in the main file.
                for suffix in ("", "-wal", "-shm"):
                    part = Path(f"{store}{suffix}")
                    if part.exists():
                        os.replace(part, Path(f"{moved}{suffix}"))
            summary = _copy(source, store)
        finally:
            source.close()
    return summary, moved


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m basestation.backup",
        description="Back up the agent's run store while it runs; restore it into a stopped "
        "agent. The store is in AGENT_DATA_DIR (or --data-dir).",
    )
    parser.add_argument("action", choices=["backup", "restore"])
    parser.add_argument("file", type=Path, help="backup: the new file; restore: the backup")
    parser.add_argument("--data-dir", type=Path, default=None, help="default: AGENT_DATA_DIR")
    args = parser.parse_args(argv)
    data_dir = args.data_dir or data_dir_from_env()
    try:
        if args.action == "backup":
            summary = store_backup(data_dir, args.file)
            print(f"backed up {summary.runs} runs, {summary.samples} samples to {args.file}")
        else:
            summary, moved = store_restore(data_dir, args.file)
            print(
                f"restored {summary.runs} runs, {summary.samples} samples from {args.file}"
                + (f"; the replaced store is {moved}" if moved else "")
                + "; start the agent"
            )
    except BackupError as exc:
        print(f"{args.action} refused: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
