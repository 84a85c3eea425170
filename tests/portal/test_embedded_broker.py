"""The embedded task transport (``portal/embedded_broker.py``) under several processes."""

from __future__ import annotations

import os
import signal
import subprocess
import time
import uuid
from collections import Counter
from pathlib import Path

import pytest

from bench.stack import REPO, python
from tests.portal.broker_peer import connection

MESSAGES = 10_000
PRODUCERS = 4
CONSUMERS = 3


_STARTED: list[subprocess.Popen[bytes]] = []


@pytest.fixture(autouse=True)
def _no_peer_left_behind():
    yield
    while _STARTED:
        process = _STARTED.pop()
        if process.poll() is None:
            process.kill()
        process.communicate()


def _peer(*args: str) -> subprocess.Popen[bytes]:
    process = subprocess.Popen(
        [python(), "-m", "tests.portal.broker_peer", *args],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
    )
    _STARTED.append(process)
    return process


def _queue_name() -> str:
    """A queue of the test's own: kombu keeps the exchanges it has declared for the whole
    process, and this process opens several transports' folders in turn."""
    return f"q{uuid.uuid4().hex}"


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.exists() else []


def _wait(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _finish(process: subprocess.Popen[bytes], timeout_s: float) -> tuple[int, str]:
    try:
        out, _ = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        out, _ = process.communicate()
    return process.returncode, out.decode(errors="replace")


def test_many_producers_and_consumers_lose_nothing_when_a_consumer_is_killed(tmp_path):
    """10 000 messages from 4 producers to 3 consumers; a 4th consumer takes a message and is
    killed with SIGKILL before acknowledging it. Every message is handled, none twice, no
    consumer dies, and nothing is left in flight."""
    per_producer = MESSAGES // PRODUCERS
    producers = [
        _peer("produce", str(tmp_path), "work", str(i * per_producer), str(per_producer))
        for i in range(PRODUCERS)
    ]
    victim_out = tmp_path / "victim.txt"
    victim = _peer("consume", str(tmp_path), "work", str(victim_out), "--hold-after", "200")
    outs = [tmp_path / f"consumer-{i}.txt" for i in range(CONSUMERS)]
    consumers = [_peer("consume", str(tmp_path), "work", str(out)) for out in outs]

    # Midway: the victim holds an unacknowledged message in its own folder; kill it. (The
    # others put it back at their next look, which may come at once: it is counted before.)
    _wait(lambda: "HOLDING" in _lines(victim_out), 120, "the victim to hold a message")
    [own] = [d for d in (tmp_path / "inflight").iterdir() if d.name.startswith(f"{victim.pid}-")]
    assert len(os.listdir(own)) == 1, "the victim should hold exactly its one message"
    victim.send_signal(signal.SIGKILL)
    victim.wait(timeout=10)

    for producer in producers:
        code, output = _finish(producer, 300)
        assert code == 0, output
    (tmp_path / "DONE").touch()
    for consumer in consumers:
        code, output = _finish(consumer, 300)
        assert code == 0, f"a consumer died: {output}"

    handled = Counter(
        line for out in [*outs, victim_out] for line in _lines(out) if line != "HOLDING"
    )
    assert set(handled) == {str(i) for i in range(MESSAGES)}, "messages were lost"
    assert [i for i, n in handled.items() if n > 1] == [], "messages were handled twice"
    assert len(_lines(victim_out)) == 201  # 200 handled, then the held one
    assert list((tmp_path / "queue").iterdir()) == []
    assert [p for p in (tmp_path / "inflight").rglob("*") if p.is_file()] == []
    assert not (tmp_path / "bad").exists()


def test_a_message_is_never_seen_half_written_and_a_damaged_file_is_set_aside(tmp_path, caplog):
    queue_dir = tmp_path / "queue"
    queue = _queue_name()
    with connection(tmp_path) as conn:
        work = conn.SimpleQueue(queue)
        # A writer still at work (its temporary file) is not a message.
        (queue_dir / ".part-123").write_bytes(b'{"body": ')
        # A damaged message file (an older writer, a full disk) does not stop the consumer.
        (queue_dir / f"0_abc.{queue}.msg").write_bytes(b'{"body": "tru')
        assert work.qsize() == 1
        work.put({"id": 7})
        message = work.get(timeout=5)
        assert message.payload == {"id": 7}
        message.ack()
        work.close()
    assert sorted(p.name for p in (tmp_path / "bad").iterdir()) == [f"0_abc.{queue}.msg"]
    assert "could not be read" in caplog.text
    assert [p.name for p in queue_dir.iterdir()] == [".part-123"]


def test_a_message_put_back_by_a_live_consumer_is_delivered_again(tmp_path):
    queue = _queue_name()
    with connection(tmp_path) as conn:
        work = conn.SimpleQueue(queue)
        work.put({"id": 1})
        first = work.get(timeout=5)
        first.requeue()
        again = work.get(timeout=5)
        assert again.payload == {"id": 1}
        again.ack()
        work.close()
    assert [p for p in (tmp_path / "inflight").rglob("*") if p.is_file()] == []
    assert list((tmp_path / "queue").iterdir()) == []


def test_processes_binding_queues_to_one_exchange_at_once_lose_no_binding(tmp_path):
    """Celery's worker, beat and web declare their queues at the same moment when ``make run``
    starts: the exchange's table of bindings is never read half written, and no binding is
    lost to another process's write."""
    binders, per_binder = 6, 150
    processes = [
        _peer("bind", str(tmp_path), "shared", f"b{i}", str(per_binder)) for i in range(binders)
    ]
    _wait(lambda: len(list(tmp_path.glob("ready-*"))) == binders, 60, "the binders to connect")
    (tmp_path / "GO").touch()
    for process in processes:
        code, output = _finish(process, 120)
        assert code == 0, output
    with connection(tmp_path) as conn:
        table = conn.default_channel.get_table("shared")
    assert sorted(row.queue for row in table) == sorted(
        f"b{i}-{n}" for i in range(binders) for n in range(per_binder)
    )


def test_the_embedded_default_uses_this_transport(tmp_path):
    """Without a broker URL (``make run``), Celery connects through this transport."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("CELERY_", "REDIS_"))}
    env.update({"DJANGO_DEBUG": "1", "AMAZING_VAR_DIR": str(tmp_path)})
    code = (
        "import django, os; os.environ['DJANGO_SETTINGS_MODULE'] = 'portal.settings'; "
        "django.setup(); from portal.celery import app; "
        "print(type(app.connection_for_write().default_channel).__module__)"
    )
    result = subprocess.run(
        [python(), "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )
    assert result.stdout.strip() == "portal.embedded_broker", result.stderr
