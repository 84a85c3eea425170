"""The system's real processes, started and stopped: one implementation for the integration
and browser tests (``tests/integration/stack.py`` makes fixtures of it), the soak
(``bench/soak/``) and the whole-system benchmarks.

- :class:`Proc`: a child in its own process group, its output kept (and written to a file
  when asked) to wait on and to show when something fails;
- :class:`RedisServer` and :class:`PostgresCluster`: private servers on free ports, which a
  test or the soak may kill and start again without touching the machine's own;
- :class:`Stack` and :func:`running_stack`: every process of ``portal.processes`` on a given
  database and Redis, started and ready, each of which can be killed and started again.

No Django here: the caller names the database by URL.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from email import message_from_bytes, policy
from email.message import EmailMessage
from pathlib import Path
from typing import Any, TextIO

import redis
import requests

from basestation.client import AgentClient
from portal.processes import ProcessSpec, system_processes

REPO = Path(__file__).resolve().parent.parent
REDIS_SERVER = "/usr/bin/redis-server"
# Debian's PostgreSQL server programs, one directory per major version.
POSTGRES_LIB = Path("/usr/lib/postgresql")
# Prometheus's bearer token for the stack's /metrics.
METRICS_TOKEN = "stack-metrics-token-0123456789"


# The servers that the suite and the benchmarks start listen on ports taken below the kernel's
# ephemeral range (32768 and up on Linux), which it hands to every outgoing connection and
# every ``bind(0)``: a port picked there can be taken by anyone between the pick and the
# server's bind. Below it, each port is reserved by a lock on a file of its own, held for the
# life of the process that took it, so that two test workers (or two checkouts' suites on one
# machine) never start servers on one port and never talk to each other's.
PORT_RANGE = (20000, 32700)
PORT_LOCKS = Path(tempfile.gettempdir()) / "amazing-ports"
_reserved: dict[int, int] = {}  # port -> the descriptor whose lock reserves it
_pick = random.SystemRandom()  # not the seeded ``random`` every worker shares the state of


def _bindable(port: int) -> bool:
    for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
        with socket.socket(socket.AF_INET, kind) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def free_port() -> int:
    """A port of 127.0.0.1, free for TCP and UDP now and reserved for this process's life."""
    PORT_LOCKS.mkdir(exist_ok=True)
    for _ in range(500):
        port = _pick.randrange(*PORT_RANGE)
        if port in _reserved:
            continue
        fd = os.open(PORT_LOCKS / f"{port}.lock", os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        if _bindable(port):
            _reserved[port] = fd
            return port
        os.close(fd)  # closing the descriptor drops its lock
    raise RuntimeError(f"no free port in {PORT_RANGE}")


class Proc:
    """A child process in its own process group whose output is kept for failure reports."""

    def __init__(
        self, name: str, argv: list[str], env: dict[str, str], *, log_path: Path | None = None
    ) -> None:
        self.name = name
        self.lines: list[str] = []
        # Appended to: a process started again goes on in the same file.
        self._log: TextIO | None = log_path.open("a") if log_path is not None else None
        self.popen = subprocess.Popen(
            argv,
            cwd=REPO,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for raw in self.popen.stdout:
            line = raw.decode(errors="replace").rstrip()
            self.lines.append(line)
            if self._log is not None:
                self._log.write(f"{time.strftime('%H:%M:%S')} {line}\n")
                self._log.flush()

    def output(self, last: int = 60) -> str:
        return "\n".join(f"{self.name}| {line}" for line in self.lines[-last:])

    def mark(self) -> int:
        """Where the output stands now: pass it as ``since`` to read only what comes after."""
        return len(self.lines)

    def wait_for_line(
        self, predicate: Callable[[str], bool], timeout_s: float, *, since: int = 0
    ) -> str:
        """The first line from ``since`` on (0: from the process's start) that ``predicate``
        accepts, waiting up to ``timeout_s`` for it."""
        deadline = time.monotonic() + timeout_s
        seen = since
        while time.monotonic() < deadline:
            while seen < len(self.lines):
                line = self.lines[seen]
                seen += 1
                if predicate(line):
                    return line
            if self.popen.poll() is not None and seen >= len(self.lines):
                break
            time.sleep(0.1)
        raise AssertionError(f"{self.name}: expected line not seen\n{self.output()}")

    def wait_for_mail(
        self, predicate: Callable[[EmailMessage], bool], timeout_s: float, *, since: int
    ) -> EmailMessage:
        """The first e-mail printed from line ``since`` on (take it with :meth:`mark` before
        the action that sends it) that ``predicate`` accepts, waiting up to ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            for message in printed_mails(self.lines[since:]):
                if predicate(message):
                    return message
            if time.monotonic() > deadline or self.popen.poll() is not None:
                raise AssertionError(f"{self.name}: expected e-mail not seen\n{self.output()}")
            time.sleep(0.1)

    def tell(self, sig: int = signal.SIGTERM) -> None:
        """Send ``sig`` to the process and its children, without waiting."""
        if self.popen.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.popen.pid, sig)

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 15) -> int:
        if self.popen.poll() is None:
            self.tell(sig)
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait()
        self._reader.join(timeout=5)
        if self.popen.stdout is not None:
            self.popen.stdout.close()
        if self._log is not None and not self._reader.is_alive():
            self._log.close()
        return self.popen.returncode

    @property
    def alive(self) -> bool:
        return self.popen.poll() is None


# Django's console e-mail backend prints each message, then a line of 79 dashes. A Celery
# worker logs what its tasks print: each write is a log record, its first line prefixed.
MAIL_SEPARATOR = "-" * 79
LOG_RECORD = re.compile(r"^\[\d{4}-\d\d-\d\d [\d:,]+: \w+/[^\]]+\] ")


def _parsed_mail(lines: list[str]) -> EmailMessage:
    # As bytes: the body is 8-bit UTF-8, which the parser decodes by its charset only so.
    raw = ("\n".join(lines) + "\n").encode()
    message = message_from_bytes(raw, policy=policy.default)
    assert isinstance(message, EmailMessage)
    # A long subject is folded onto the next lines; unfolded, it keeps a leading space.
    subject = message["Subject"]
    if subject is not None:
        message.replace_header("Subject", str(subject).strip())
    return message


def printed_mails(lines: list[str]) -> list[EmailMessage]:
    """The complete e-mails the console backend printed in ``lines``, parsed one by one (the
    subject decoded). A message ends at its separator or at the next log record: one printed
    by another thread in between never merges into it."""
    found: list[EmailMessage] = []
    block: list[str] | None = None
    for line in lines:
        starts_record = LOG_RECORD.match(line) is not None
        if block is not None and (line.endswith(MAIL_SEPARATOR) or starts_record):
            found.append(_parsed_mail(block))
            block = None
        if block is not None:
            block.append(line)
        elif (at := line.find("Content-Type: ")) >= 0 and (starts_record or at == 0):
            block = [line[at:]]
    return found


def wait_http(url: str, timeout_s: float, procs: list[Proc], *, server: Proc | None = None) -> None:
    """Wait until ``url`` answers. With ``server``, the answer counts only while that process
    lives: a server that could not bind its port has exited, and whatever else answers there
    is not it."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if server is not None and not server.alive:
            break
        try:
            requests.get(url, timeout=5)
        except requests.RequestException:
            # Refused while the server starts, or too slow to answer under load: try again.
            time.sleep(0.2)
            continue
        if server is None or server.alive:
            return
    raise AssertionError(f"{url} did not answer\n" + "\n".join(p.output() for p in procs))


def python() -> str:
    return sys.executable


def wait_until(
    what: str, check: Callable[[], Any], timeout_s: float, *, step_s: float = 0.2
) -> Any:
    """Poll ``check`` until it returns something truthy (errors of a server that is not up yet
    count as not yet); that value, or ``TimeoutError`` naming ``what``."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            value = check()
        except (requests.RequestException, redis.RedisError, OSError):
            value = None
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out waiting for {what}")
        time.sleep(step_s)


class RedisServer:
    """A private redis-server on a free port, without persistence: stopping it loses its
    data, as a crashed cache/broker without an append-only file would. Started again, it
    listens on the same port."""

    def __init__(self, directory: Path) -> None:
        assert shutil.which(REDIS_SERVER), "redis-server is installed with the test services"
        self.directory = directory
        self.directory.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.proc: Proc | None = None

    def url(self, db: int) -> str:
        return f"redis://127.0.0.1:{self.port}/{db}"

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.alive

    def start(self) -> None:
        argv = [REDIS_SERVER, "--port", str(self.port), "--bind", "127.0.0.1"]
        argv += ["--save", "", "--appendonly", "no", "--dir", str(self.directory)]
        self.proc = Proc("redis", argv, dict(os.environ))
        client = redis.Redis(port=self.port, socket_connect_timeout=0.5)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            if not self.proc.alive:
                break
            with contextlib.suppress(redis.RedisError):
                # Ours, not another server that answers on the port.
                if client.info("server")["process_id"] == self.proc.popen.pid:
                    return
            time.sleep(0.1)
        raise AssertionError(f"redis-server did not start\n{self.proc.output()}")

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc is not None:
            self.proc.stop(sig)
            self.proc = None


def postgres_bindir() -> Path:
    """The newest PostgreSQL server installed (Debian's layout)."""
    versions = sorted(
        (d for d in POSTGRES_LIB.glob("*/bin") if (d / "initdb").exists()),
        key=lambda d: int(d.parent.name) if d.parent.name.isdigit() else 0,
    )
    assert versions, f"no PostgreSQL server under {POSTGRES_LIB}"
    return versions[-1]


class PostgresCluster:
    """A private PostgreSQL cluster (``initdb`` in a scratch directory of its own) on a free
    port of 127.0.0.1, trust authentication, so that it can be restarted (or crashed) without
    disturbing the machine's server. As root, the server runs as the ``postgres`` user
    (PostgreSQL refuses to run as root), which must reach the directory: it lies in the
    system's temporary directory, not under a caller's private one. :meth:`remove` deletes it.
    """

    def __init__(self) -> None:
        self.directory = Path(tempfile.mkdtemp(prefix="amazing-postgres-"))
        self.data = self.directory / "data"
        self.log = self.directory / "postgres.log"
        self.port = free_port()
        self.bindir = postgres_bindir()
        self.user = "postgres" if os.geteuid() == 0 else None

    def url(self, database: str) -> str:
        return f"postgres://postgres@127.0.0.1:{self.port}/{database}"

    def _run(self, program: str, *args: str) -> None:
        done = subprocess.run(
            [str(self.bindir / program), *args],
            cwd=self.directory,
            user=self.user,
            check=False,
            capture_output=True,
            text=True,
            stdin=subprocess.DEVNULL,
        )
        if done.returncode != 0:
            raise RuntimeError(f"{program} {' '.join(args)}: {done.stdout}{done.stderr}")

    def init(self) -> None:
        if self.user is not None:
            shutil.chown(self.directory, self.user)
        self._run("initdb", "-D", str(self.data), "-U", "postgres", "-A", "trust", "-E", "UTF8")

    def start(self) -> None:
        options = f"-p {self.port} -c listen_addresses=127.0.0.1 -k {self.directory}"
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.log), "-o", options, "-w", "start")

    def stop(self, mode: str = "fast") -> None:
        """``mode`` as pg_ctl's: ``fast`` (roll back and disconnect) or ``immediate`` (quit
        at once, as a crash: recovery on the next start)."""
        self._run("pg_ctl", "-D", str(self.data), "-m", mode, "-w", "stop")

    def remove(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)

    def create_database(self, name: str) -> None:
        import psycopg

        with psycopg.connect(self.url("postgres"), autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')


class Stack:
    """The running system: addresses, agent clients, and its processes by name."""

    def __init__(
        self, specs: list[ProcessSpec], env: dict[str, str], *, log_dir: Path | None = None
    ) -> None:
        self.specs = {spec.name: spec for spec in specs}
        self.env = env
        self.log_dir = log_dir
        self.procs: dict[str, Proc] = {}
        self.web = ""
        self.streams = ""
        self.agent_url = ""
        self.token = ""
        self.agent: AgentClient | None = None
        self.agent2_url = ""
        self.token2 = ""
        self.agent2: AgentClient | None = None
        self.redis: RedisServer | None = None
        # The stand-in scheduler, when the stack has one.
        self.standin = ""

    # The original fixture handed out a dict; its tests keep reading it that way.
    def __getitem__(self, key: str) -> Any:
        if key == "procs":
            return list(self.procs.values())
        return getattr(self, key)

    def start(self, name: str) -> Proc:
        """Start (or start again) the process ``name`` with its command and environment."""
        spec = self.specs[name]
        log_path = self.log_dir / f"{name}.log" if self.log_dir is not None else None
        self.procs[name] = Proc(name, list(spec.argv), {**self.env, **spec.env}, log_path=log_path)
        return self.procs[name]

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Stop ``name`` and its children: SIGKILL by default (no chance to clean up)."""
        self.procs[name].stop(sig)

    def wait_ready(self, name: str, timeout_s: float = 30) -> None:
        running = list(self.procs.values())
        server = self.procs[name]
        if name.startswith("agent"):
            url = self.agent_url if name == "agent" else self.agent2_url
            wait_http(f"{url}/healthz", timeout_s, running, server=server)
        elif name == "web":
            wait_http(f"{self.web}/accounts/login/", timeout_s, running, server=server)
        elif name == "streams":
            wait_http(f"{self.streams}/healthz", timeout_s, running, server=server)
        elif name == "scheduler":
            wait_http(f"{self.standin}/resources/nodes", timeout_s, running, server=server)
        elif name in ("worker", "mail"):
            self.procs[name].wait_for_line(lambda line: "ready." in line, timeout_s)
        elif name == "collector":
            self.procs[name].wait_for_line(lambda line: "collector ready" in line, timeout_s)

    def output(self, last: int = 80) -> str:
        return "\n".join(p.output(last) for p in self.procs.values())

    def stop(self) -> None:
        # Every process told at once, then each waited for: their shutdowns (a worker's
        # warm one, a web server's) overlap instead of adding up, test after test.
        procs = list(reversed(list(self.procs.values())))
        for proc in procs:
            proc.tell()
        for proc in procs:
            proc.stop()


@contextlib.contextmanager
def running_stack(
    var_dir: Path,
    *,
    database_url: str,
    broker_url: str,
    redis_url: str | None = None,
    second_robot: bool = False,
    with_scheduler: bool = False,
    extra_env: dict[str, str] | None = None,
    log_dir: Path | None = None,
    access_log: bool = True,
    process_env: Mapping[str, Mapping[str, str]] | None = None,
) -> Iterator[Stack]:
    """Every process of ``system_processes`` on ``database_url`` (PostgreSQL, migrated) and
    the Redis of ``broker_url``, started and ready.

    ``second_robot`` adds a second agent (``mobile-2``, its own token in ``AGENT_TOKENS``);
    ``with_scheduler`` the stand-in scheduler (its test controls on) as ``SCHEDULER_URL``,
    swept every second unless ``extra_env`` says otherwise; ``log_dir`` keeps each process's
    output in a file there too; ``process_env`` adds to one process's environment by its
    name (``{"agent-2": {"AGENT_SIM_CONFIG": ...}}``: a robot of its own kind).
    """
    assert database_url.startswith("postgres"), "the stack runs on PostgreSQL"
    assert broker_url.startswith("redis://"), "the stack runs on Redis"
    redis.Redis.from_url(broker_url).flushdb()

    token = secrets.token_urlsafe(24)
    agent_port, web_port, streams_port = free_port(), free_port(), free_port()
    second_port = free_port() if second_robot else None
    var_dir.mkdir(parents=True, exist_ok=True)
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.update(
        {
            "DJANGO_DEBUG": "1",
            "DATABASE_URL": database_url,
            "CELERY_BROKER_URL": broker_url,
            "AGENT_TOKEN": token,
            "METRICS_TOKEN": METRICS_TOKEN,
            "AGENT_DATA_DIR": str(var_dir / "agent"),
            "AMAZING_VAR_DIR": str(var_dir),
            "RUN_SWEEP_INTERVAL_S": "0.5",
            "PYTHONUNBUFFERED": "1",
            "LIVE_STREAM_PORT": str(streams_port),
            # Two small web processes: the stack shares two cores with the rest.
            "WEB_WORKERS": "2",
            "WEB_THREADS": "4",
        }
    )
    for key in ("AGENT_TOKEN_FILE", "AGENT_TOKENS", "AGENT_TOKENS_FILE"):
        env.pop(key, None)
    if redis_url is not None:
        env["REDIS_URL"] = redis_url
    token2 = ""
    if second_robot:
        token2 = secrets.token_urlsafe(24)
        (var_dir / "agent-2-token").write_text(token2)
        env["AGENT_TOKENS"] = f"mobile-2={token2}"
    standin_port = free_port() if with_scheduler else None
    if standin_port is not None:
        env["SCHEDULER_URL"] = f"http://127.0.0.1:{standin_port}"
        env["SCHEDULER_SYNC_INTERVAL_S"] = "1"
    env.update(extra_env or {})
    specs = system_processes(
        python=python(),
        portal_port=web_port,
        streams_port=streams_port,
        agent_port=agent_port,
        var_dir=var_dir,
        access_log=access_log,
        second_agent_port=second_port,
        standin_port=standin_port,
        standin_test_control=True,
    )
    specs = [
        replace(spec, env={**spec.env, **(process_env or {}).get(spec.name, {})}) for spec in specs
    ]
    stack = Stack(specs, env, log_dir=log_dir)
    stack.web = f"http://127.0.0.1:{web_port}"
    stack.streams = f"http://127.0.0.1:{streams_port}"
    stack.agent_url = f"http://127.0.0.1:{agent_port}"
    stack.token = token
    stack.agent = AgentClient(stack.agent_url, token)
    if standin_port is not None:
        stack.standin = f"http://127.0.0.1:{standin_port}"
    if second_port is not None:
        stack.agent2_url = f"http://127.0.0.1:{second_port}"
        stack.token2 = token2
        stack.agent2 = AgentClient(stack.agent2_url, token2)
    try:
        for spec in specs:
            stack.start(spec.name)
        for name in stack.specs:
            if name != "beat":
                stack.wait_ready(name)
        yield stack
    finally:
        stack.stop()
