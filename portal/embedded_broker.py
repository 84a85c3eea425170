"""The task transport of ``make run``: kombu's filesystem transport, made safe to share.

kombu's own filesystem transport writes a message file in place (a consumer can read it half
written and die on the JSON), and deletes a message when a consumer takes it (a consumer killed
before it acknowledged loses the message, although the tasks are acknowledged late so that a
redelivery is what recovers them). This subclass changes exactly those two steps:

- **write**: a message is written to a hidden temporary file in the queue's folder and renamed
  into place, so a consumer sees a whole message or none;
- **bindings**: the table of queues bound to an exchange is changed under an exclusive lock on a
  file of its own and replaced with one rename (kombu's truncates it in place, so a process
  starting beside another could read an empty table and die on the JSON);
- **take**: a consumer claims a message by renaming it into a folder of its own under
  ``inflight_folder`` (one rename: one consumer wins); the file is removed when the message is
  acknowledged (or rejected), and put back into the queue when the message is restored. Files
  claimed by a consumer that has died are put back by any other consumer (checked at start and
  every ``RECOVER_EVERY_S`` while consuming), so a message taken by a process killed with
  SIGKILL is delivered again.

A file that still cannot be read (written by an older version, or damaged on disk) is moved to
``bad_folder`` with a log line; it never stops a consumer.

Used through the broker URL ``filesystem://`` with ``broker_transport`` naming this class
(``portal/settings.py``). Every folder must be on one file system: renames are what make it safe.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import time
import uuid
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from queue import Empty
from typing import Any

from kombu.exceptions import ChannelError
from kombu.transport import filesystem, virtual
from kombu.utils.json import dumps, loads

logger = logging.getLogger(__name__)

# How often a consuming process looks for messages held by consumers that have died.
RECOVER_EVERY_S = 5.0
# How long one listing of the queue's folder is used before it is read again: a message
# written meanwhile waits at most this long (the sweeps' tasks expire after two sweeps).
LISTING_TTL_S = 0.2
# The key under a message's properties that names the file holding it while it is in flight.
INFLIGHT_PROPERTY = "x_inflight_path"
# A temporary file starts with a dot: kombu's listing takes it for no queue's message.
_TEMPORARY_PREFIX = ".part-"
_MESSAGE_SUFFIX = ".msg"


def _start_ticks(pid: int) -> str | None:
    """The process's start time in clock ticks since boot (field 22 of /proc/PID/stat), which
    tells a process from a later one that reuses its pid; ``None`` if there is no such
    process. Where /proc does not exist, whether the pid answers a signal."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        if Path("/proc/self/stat").exists():
            return None
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass
        return "?"
    # The command name (field 2) is in parentheses and may hold spaces: split after it.
    return stat.rsplit(")", 1)[1].split()[19]


def _owner_name(pid: int) -> str | None:
    ticks = _start_ticks(pid)
    return None if ticks is None else f"{pid}-{ticks}"


def _owner_alive(name: str) -> bool:
    pid_text, _, ticks = name.partition("-")
    if not pid_text.isdigit():
        return True  # not a folder this transport made: leave it alone
    current = _start_ticks(int(pid_text))
    return current is not None and (current == ticks or "?" in (current, ticks))


class QoS(virtual.QoS):
    """Acknowledging or rejecting a message removes its in-flight file."""

    channel: Channel

    def ack(self, delivery_tag: Any) -> None:
        message = self._delivered.get(delivery_tag) if self._delivered is not None else None
        super().ack(delivery_tag)
        self.channel.forget(message)

    def reject(self, delivery_tag: Any, requeue: bool = False) -> None:
        message = self._delivered.get(delivery_tag) if self._delivered is not None else None
        super().reject(delivery_tag, requeue=requeue)  # requeue writes the message anew
        self.channel.forget(message)


class Channel(filesystem.Channel):
    QoS = QoS

    _recovered_at = float("-inf")

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for folder in (self.data_folder_in, self.data_folder_out, self.control_folder):
            Path(folder).mkdir(parents=True, exist_ok=True)
        self._listings: dict[str, tuple[float, deque[str]]] = {}
        self._owner = _owner_name(os.getpid()) or str(os.getpid())
        self.recover_orphans()

    # Folders (kombu's options, plus two of this transport's).
    @property
    def inflight_folder(self) -> Path:
        default = Path(self.data_folder_in).parent / "inflight"
        return Path(self.transport_options.get("inflight_folder", default))

    @property
    def bad_folder(self) -> Path:
        default = Path(self.data_folder_in).parent / "bad"
        return Path(self.transport_options.get("bad_folder", default))

    def _put(self, queue: str, payload: Any, **kwargs: Any) -> None:  # type: ignore[override]
        """Write the message whole, then make it visible with one rename."""
        folder = Path(self.data_folder_out)
        # The time first, as kombu names them: consumers take messages in name order.
        name = f"{round(time.monotonic() * 1000)}_{uuid.uuid4()}.{queue}{_MESSAGE_SUFFIX}"
        temporary = folder / f"{_TEMPORARY_PREFIX}{uuid.uuid4()}"
        try:
            with open(temporary, "wb") as out:
                out.write(dumps(payload).encode())
            os.replace(temporary, folder / name)
        except OSError as exc:
            with contextlib.suppress(OSError):
                temporary.unlink()
            raise ChannelError(f"cannot add message {name!r} to {folder}") from exc

    # Exchange tables (kombu keeps them as JSON files in the control folder).
    def _table_file(self, exchange: str) -> Path:
        """kombu's file of the exchange's table (it refuses names that are not a file's)."""
        file: Path = self._exchange_file(exchange)  # type: ignore[attr-defined]
        return file

    # (Typed as kombu's filesystem channel has it; kombu's stubs type the base class apart.)
    def get_table(self, exchange: str) -> list[filesystem.exchange_queue_t]:  # type: ignore[override]
        try:
            text = self._table_file(exchange).read_bytes()
        except FileNotFoundError:
            return []
        except OSError as exc:
            raise ChannelError(f"cannot read the bindings of exchange {exchange!r}") from exc
        return [filesystem.exchange_queue_t(*row) for row in loads(text.decode())]

    def _queue_bind(  # type: ignore[override]
        self, exchange: str, routing_key: str, pattern: str, queue: str
    ) -> None:
        bound = filesystem.exchange_queue_t(routing_key or "", pattern or "", queue or "")
        with self._table_changed(exchange) as table:
            if bound not in table:
                table.insert(0, bound)

    def _delete(
        self, queue: str, exchange: str, routing_key: str, pattern: str, *args: Any, **kwargs: Any
    ) -> None:
        virtual.Channel._delete(self, queue, exchange, routing_key, pattern, *args, **kwargs)
        bound = filesystem.exchange_queue_t(routing_key or "", pattern or "", queue or "")
        with self._table_changed(exchange) as table:
            if bound in table:
                table.remove(bound)

    @contextlib.contextmanager
    def _table_changed(self, exchange: str) -> Iterator[list[filesystem.exchange_queue_t]]:
        """The exchange's table to change in place; written back whole when the block ends.
        One process at a time: an exclusive lock on a lock file of the exchange's own (the
        table itself is replaced, so it cannot carry the lock)."""
        file = self._table_file(exchange)
        try:
            with open(file.with_name(f"{file.name}.lock"), "a") as lock:
                fcntl.flock(lock.fileno(), fcntl.LOCK_EX)
                table = self.get_table(exchange)
                before = list(table)
                yield table
                if table != before:
                    temporary = file.with_name(f"{_TEMPORARY_PREFIX}{uuid.uuid4()}")
                    temporary.write_bytes(dumps(table).encode())
                    os.replace(temporary, file)
        except OSError as exc:
            raise ChannelError(f"cannot change the bindings of exchange {exchange!r}") from exc

    def _get(self, queue: str, timeout: float | None = None) -> Any:
        """Claim the oldest message of ``queue`` by moving it into this consumer's folder."""
        if time.monotonic() - self._recovered_at >= RECOVER_EVERY_S:
            self.recover_orphans()
        folder = Path(self.data_folder_in)
        mine = self.inflight_folder / self._owner
        for name in self._candidates(queue):
            mine.mkdir(parents=True, exist_ok=True)
            claimed = mine / name
            try:
                os.rename(folder / name, claimed)
            except FileNotFoundError:
                continue  # another consumer took it first
            try:
                payload = loads(claimed.read_bytes().decode())
                payload["properties"][INFLIGHT_PROPERTY] = str(claimed)
            except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
                self._set_aside(claimed, exc)
                continue
            return payload
        raise Empty()

    def _candidates(self, queue: str) -> Iterator[str]:
        """The queue's message names, oldest first, from one listing of the folder kept for a
        short while: listing a folder of thousands of messages for every message taken would
        cost more than the work."""
        wanted = f"{queue}{_MESSAGE_SUFFIX}"
        listed_at, names = self._listings.get(queue, (float("-inf"), deque()))
        if not names or time.monotonic() - listed_at > LISTING_TTL_S:
            names = deque(
                sorted(n for n in os.listdir(self.data_folder_in) if n.partition(".")[2] == wanted)
            )
            self._listings[queue] = (time.monotonic(), names)
        while names:
            yield names.popleft()

    def _restore(self, message: Any) -> None:
        """Put an unacknowledged message back (warm shutdown, connection loss)."""
        super()._restore(message)
        self.forget(message)

    def forget(self, message: Any) -> None:
        """Remove the in-flight file of a message that is acknowledged, rejected or restored."""
        if message is None:
            return
        path = message.properties.get(INFLIGHT_PROPERTY)
        if path:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)

    def recover_orphans(self) -> int:
        """Put back into the queue every message claimed by a consumer that no longer runs."""
        self._recovered_at = time.monotonic()
        recovered = 0
        try:
            owners = os.listdir(self.inflight_folder)
        except FileNotFoundError:
            return 0
        for owner in owners:
            if owner == self._owner or _owner_alive(owner):
                continue
            held = self.inflight_folder / owner
            try:
                names = sorted(os.listdir(held))
            except (FileNotFoundError, NotADirectoryError):
                continue  # another consumer recovered it and removed the folder meanwhile
            for name in names:
                with contextlib.suppress(FileNotFoundError):  # another consumer was quicker
                    os.rename(held / name, Path(self.data_folder_in) / name)
                    recovered += 1
            with contextlib.suppress(OSError):
                held.rmdir()
        if recovered:
            logger.warning(
                "task transport: %d message(s) held by a consumer that stopped are queued again",
                recovered,
            )
        return recovered

    def _set_aside(self, path: Path, error: Exception) -> None:
        self.bad_folder.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):
            os.replace(path, self.bad_folder / path.name)
        logger.error(
            "task transport: message %s could not be read (%s); moved to %s",
            path.name,
            error,
            self.bad_folder,
        )


class Transport(filesystem.Transport):
    """kombu's filesystem transport with atomic writes and redelivery after a consumer's death."""

    Channel = Channel
    global_state = virtual.BrokerState()
