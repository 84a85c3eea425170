"""A producer or consumer of the embedded task transport, as its own process.

    python -m tests.portal.broker_peer produce FOLDER QUEUE FIRST COUNT
    python -m tests.portal.broker_peer consume FOLDER QUEUE OUT_FILE [--hold-after N]

A producer publishes the ids FIRST … FIRST+COUNT-1. A consumer writes each id it has handled to
OUT_FILE (one a line, flushed) and then acknowledges it; it stops when DONE appears in FOLDER
and neither the queue nor any consumer's in-flight folder holds a message. With
``--hold-after N`` it takes an (N+1)th message and never acknowledges it, writing HOLDING to
its file — the test then kills it.
"""

from __future__ import annotations

import queue as stdlib_queue
import sys
import time
from pathlib import Path

from kombu import Connection

TRANSPORT = "portal.embedded_broker:Transport"


def connection(folder: Path) -> Connection:
    return Connection(
        "filesystem://",
        transport=TRANSPORT,
        transport_options={
            "data_folder_in": str(folder / "queue"),
            "data_folder_out": str(folder / "queue"),
            "inflight_folder": str(folder / "inflight"),
            "bad_folder": str(folder / "bad"),
            "control_folder": str(folder / "control"),
        },
    )


def produce(folder: Path, name: str, first: int, count: int) -> None:
    with connection(folder) as conn:
        work = conn.SimpleQueue(name)
        for number in range(first, first + count):
            work.put({"id": number})
        work.close()


def consume(folder: Path, name: str, out_file: Path, hold_after: int | None) -> None:
    handled = 0
    with connection(folder) as conn, out_file.open("a", buffering=1) as out:
        work = conn.SimpleQueue(name)
        work.consumer.qos(prefetch_count=1)
        while True:
            try:
                message = work.get(block=True, timeout=0.5)
            except stdlib_queue.Empty:
                # Done when the producers are, nothing is queued, and nothing is held in
                # flight (a killed consumer's message is put back within a few seconds).
                held = any(p.is_file() for p in (folder / "inflight").rglob("*"))
                if (folder / "DONE").exists() and work.qsize() == 0 and not held:
                    break
                continue
            if hold_after is not None and handled >= hold_after:
                out.write("HOLDING\n")
                while True:  # a task that never ends: the test kills this process
                    time.sleep(60)
            out.write(f"{message.payload['id']}\n")
            message.ack()
            handled += 1
        work.close()


def main(argv: list[str]) -> int:
    role, folder, name = argv[0], Path(argv[1]), argv[2]
    if role == "produce":
        produce(folder, name, int(argv[3]), int(argv[4]))
    else:
        hold_after = int(argv[5]) if len(argv) > 5 and argv[4] == "--hold-after" else None
        consume(folder, name, Path(argv[3]), hold_after)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
