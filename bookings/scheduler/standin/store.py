"""The stand-in broker's leases and where they are kept: in memory, or written through to a
SQLite file that keeps them across restarts (``--db``)."""

from __future__ import annotations

import json
import sqlite3
import threading
from dataclasses import dataclass


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
