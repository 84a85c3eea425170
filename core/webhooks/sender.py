"""One try of one webhook: a signed POST to the checked address, answered or not.

Short timeouts, the answer read up to a small limit and thrown away (only its status matters),
redirects never followed: a 3xx is a failed try like any answer but 2xx.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

import certifi
import urllib3
from standardwebhooks import Webhook

from core.webhooks.guard import Target

USER_AGENT = "AMazING-webhooks/1"
CONNECT_TIMEOUT_S = 3.0
READ_TIMEOUT_S = 5.0
ANSWER_MAX_BYTES = 4096


@dataclass(frozen=True)
class Answer:
    status: int | None  # None: no answer (refused, timed out, TLS failed)
    error: str  # why it failed; empty on 2xx

    @property
    def ok(self) -> bool:
        return self.status is not None and 200 <= self.status < 300


def signed_headers(*, secret: str, msg_id: str, sent_at: datetime, body: str) -> dict[str, str]:
    """Standard Webhooks' three headers (``standardwebhooks`` signs)."""
    return {
        "webhook-id": msg_id,
        "webhook-timestamp": str(int(sent_at.timestamp())),
        "webhook-signature": Webhook(secret).sign(msg_id, sent_at, body),
    }


def _pool(target: Target) -> urllib3.HTTPConnectionPool:
    timeout = urllib3.Timeout(connect=CONNECT_TIMEOUT_S, read=READ_TIMEOUT_S)
    if target.scheme == "https":
        return urllib3.HTTPSConnectionPool(
            target.address,
            target.port,
            timeout=timeout,
            retries=False,
            cert_reqs="CERT_REQUIRED",
            ca_certs=certifi.where(),
            server_hostname=target.host,
            assert_hostname=target.host,
        )
    return urllib3.HTTPConnectionPool(target.address, target.port, timeout=timeout, retries=False)


def webhook_post(target: Target, *, body: str, headers: dict[str, str]) -> Answer:
    host = target.host if ":" not in target.host else f"[{target.host}]"
    default_port = 443 if target.scheme == "https" else 80
    pool = _pool(target)
    try:
        answer = pool.urlopen(
            "POST",
            target.path,
            body=body.encode("utf-8"),
            headers={
                **headers,
                "Host": host if target.port == default_port else f"{host}:{target.port}",
                "Content-Type": "application/json",
                "User-Agent": USER_AGENT,
            },
            redirect=False,
            retries=False,
            preload_content=False,
        )
        try:
            answer.read(ANSWER_MAX_BYTES)
        finally:
            answer.release_conn()
    except urllib3.exceptions.HTTPError as exc:
        return Answer(None, f"no answer: {type(exc).__name__}: {exc}"[:300])
    finally:
        pool.close()
    if 200 <= answer.status < 300:
        return Answer(answer.status, "")
    if 300 <= answer.status < 400:
        return Answer(answer.status, "a redirect: not followed")
    return Answer(answer.status, f"answered {answer.status}")
