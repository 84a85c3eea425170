"""A producer or consumer of the embedded task transport, as its own process.

    python -m tests.portal.broker_peer produce FOLDER QUEUE FIRST COUNT
    python -m tests.portal.broker_peer consume FOLDER QUEUE OUT_FILE [--hold-after N]
    python -m tests.portal.broker_peer bind FOLDER EXCHANGE PREFIX COUNT

A producer publishes the ids FIRST … FIRST+COUNT-1. A consumer writes each id it has handled to
OUT_FILE (one a line, flushed) and then acknowledges it; it stops when DONE appears in FOLDER
and neither the queue nor any consumer's in-flight folder holds a message. With
``--hold-after N`` it takes an (N+1)th message and never acknowledges it, writing HOLDING to
its file — the test then kills it. A binder writes ready-PREFIX to FOLDER once connected and,
when GO appears there, declares the queues PREFIX-0 … PREFIX-(COUNT-1) bound to EXCHANGE,
reading the exchange's table after each.
"""

from __future__ import annotations

import os
import queue as stdlib_queue
import sys
import time
from pathlib import Path

from kombu import Connection, Exchange, Queue

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


def _anything_in_flight(inflight: Path) -> bool:
    # os.walk rather than Path.rglob: another consumer may remove a dead one's folder
    # between the listing and the look inside, which rglob raises on.
    return any(files for _, _, files in os.walk(inflight))


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
                held = _anything_in_flight(folder / "inflight")
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


def bind(folder: Path, exchange_name: str, prefix: str, count: int) -> None:
    with connection(folder) as conn:
        channel = conn.default_channel
        exchange = Exchange(exchange_name, type="direct", durable=False)
        (folder / f"ready-{prefix}").touch()
        while not (folder / "GO").exists():  # all binders start together
            time.sleep(0.01)
        for number in range(count):
            queue_name = f"{prefix}-{number}"
            Queue(queue_name, exchange, routing_key=queue_name)(channel).declare()
            channel.get_table(exchange_name)  # raises if it ever reads a half-written table


def main(argv: list[str]) -> int:
    role, folder, name = argv[0], Path(argv[1]), argv[2]
    if role == "bind":
        bind(folder, name, argv[3], int(argv[4]))
    elif role == "produce":
        produce(folder, name, int(argv[3]), int(argv[4]))
    else:
        hold_after = int(argv[5]) if len(argv) > 5 and argv[4] == "--hold-after" else None
        consume(folder, name, Path(argv[3]), hold_after)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
