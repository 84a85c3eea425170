"""A webhook receiver of the tests' own, as a process: real HTTP on loopback.

Run as ``python -m tests.core.webhook_receiver LOG PORT_FILE``; the environment gives
``WEBHOOK_SECRET``, ``FAIL_FIRST`` (answer 500 to the first N requests), ``HOLD_FIRST_S`` (answer
the first request only after this long), ``REDIRECT`` (answer every request 302 to there) and
``PORT`` (0: any free one). It prints nothing; it writes the port it listens on to PORT_FILE and,
as each request arrives (before it answers), one JSON line to LOG: the ``webhook-id``, the
event's type and id, whether ``standardwebhooks`` verified it and the answer it gives.

:class:`Receiver` runs it for a test, and stops and starts it again on its port.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from standardwebhooks import Webhook
from standardwebhooks.webhooks import WebhookVerificationError


def main() -> None:
    log, port_file = Path(sys.argv[1]), Path(sys.argv[2])
    verifier = Webhook(os.environ["WEBHOOK_SECRET"])
    fail_first = int(os.environ.get("FAIL_FIRST", "0"))
    hold_first_s = float(os.environ.get("HOLD_FIRST_S", "0"))
    seen = [0]

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
            seen[0] += 1
            try:
                event = verifier.verify(body, dict(self.headers.items()))
                verified = True
            except WebhookVerificationError:
                event, verified = json.loads(body), False
            redirect = os.environ.get("REDIRECT", "")
            answer = 302 if redirect else 500 if seen[0] <= fail_first else 200
            with log.open("a") as out:
                line = {
                    "webhook_id": self.headers.get("webhook-id"),
                    "type": event.get("type"),
                    "id": event.get("id"),
                    "verified": verified,
                    "answer": answer,
                }
                out.write(json.dumps(line) + "\n")
            if seen[0] == 1 and hold_first_s:
                time.sleep(hold_first_s)
            self.send_response(answer)
            if redirect:
                self.send_header("Location", redirect)
            self.send_header("Content-Length", "0")
            self.end_headers()

        def log_message(self, format: str, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", int(os.environ.get("PORT", "0"))), Handler)
    port_file.write_text(str(server.server_address[1]))
    server.serve_forever()


REPO = Path(__file__).resolve().parents[2]
DEADLINE_S = 30.0  # bounds a hang only


class Receiver:
    """``tests/core/webhook_receiver.py`` as a process; stopped and started again on its port."""

    def __init__(self, directory: Path, secret: str, **env: str) -> None:
        self.log = directory / "received.jsonl"
        self.port_file = directory / "port"
        self.secret = secret
        self.env = env
        self.port = 0
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.port_file.unlink(missing_ok=True)
        env = {
            **os.environ,
            "PYTHONPATH": str(REPO),
            "WEBHOOK_SECRET": self.secret,
            "PORT": str(self.port),
            **self.env,
        }
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tests.core.webhook_receiver",
                str(self.log),
                str(self.port_file),
            ],
            env=env,
        )
        deadline = time.monotonic() + DEADLINE_S
        while not self.port_file.exists() or not self.port_file.read_text():
            assert self.process.poll() is None, "the receiver died"
            assert time.monotonic() < deadline, "the receiver never listened"
            time.sleep(0.05)
        self.port = int(self.port_file.read_text())

    def stop(self) -> None:
        if self.process is not None:
            self.process.terminate()
            self.process.wait(10)
            self.process = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/hook"

    def received(self) -> list[dict[str, Any]]:
        if not self.log.exists():
            return []
        return [json.loads(line) for line in self.log.read_text().splitlines()]


if __name__ == "__main__":
    main()
