"""Start and stop the system's real processes for integration tests."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from email import message_from_bytes, policy
from email.message import EmailMessage
from pathlib import Path

import requests

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class Proc:
    """A child process in its own process group whose output is kept for failure reports."""

    def __init__(self, name: str, argv: list[str], env: dict[str, str]) -> None:
        self.name = name
        self.lines: list[str] = []
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
            self.lines.append(raw.decode(errors="replace").rstrip())

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

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 15) -> int:
        if self.popen.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.popen.pid, sig)
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait()
        self._reader.join(timeout=5)
        if self.popen.stdout is not None:
            self.popen.stdout.close()
        return self.popen.returncode


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


def wait_http(url: str, timeout_s: float, procs: list[Proc]) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            requests.get(url, timeout=5)
            return
        except requests.RequestException:
            # Refused while the server starts, or too slow to answer under load: try again.
            time.sleep(0.2)
    raise AssertionError(f"{url} did not answer\n" + "\n".join(p.output() for p in procs))


def python() -> str:
    return sys.executable


def processes_matching_env(key: str, value: str) -> list[int]:
    """PIDs of live processes whose environment holds ``key=value`` (Linux /proc)."""
    needle = f"{key}={value}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            environ = (entry / "environ").read_bytes().split(b"\0")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if needle in environ and state != "Z":
            found.append(int(entry.name))
    return found
