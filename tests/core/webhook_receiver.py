"""A webhook receiver of the tests' own, as a process: real HTTP on loopback.

Run as ``python -m tests.core.webhook_receiver LOG PORT_FILE``; the environment gives
``WEBHOOK_SECRET``, ``FAIL_FIRST`` (answer 500 to the first N requests), ``REDIRECT`` (answer
every request 302 to there) and ``PORT`` (0: any free one). It prints nothing;
it writes the port it listens on to PORT_FILE and one JSON line per request to LOG: the
``webhook-id``, the event's type and id, and whether ``standardwebhooks`` verified it.
"""

from __future__ import annotations

import json
import os
import sys
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from standardwebhooks import Webhook
from standardwebhooks.webhooks import WebhookVerificationError


def main() -> None:
    log, port_file = Path(sys.argv[1]), Path(sys.argv[2])
    verifier = Webhook(os.environ["WEBHOOK_SECRET"])
    fail_first = int(os.environ.get("FAIL_FIRST", "0"))
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


if __name__ == "__main__":
    main()
