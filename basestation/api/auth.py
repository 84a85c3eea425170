"""Bearer-token check for every ``/api/v1`` request, and the token's scope.

Two scopes: the **control** token (the portal's) may do everything; a **read-only** token
(metrics, status: a Prometheus scraper) may read (``GET``/``HEAD``) and latch the e-stop —
whoever can see that the robot must stop may stop it — but never drive, release the stop,
stage or delete a run (403).
"""

from __future__ import annotations

import hashlib
import hmac

from flask import request
from werkzeug.datastructures import WWWAuthenticate
from werkzeug.exceptions import Forbidden, Unauthorized

from basestation.contract import STOP_PATH
from basestation.runtime import get_runtime

PROTECTED_PREFIX = "/api/v1"
READ_METHODS = frozenset({"GET", "HEAD"})


def read_only_may(method: str, path: str) -> bool:
    """What a read-only token may do: read anything, and stop the robot (safety first)."""
    return method in READ_METHODS or (method == "POST" and path == STOP_PATH)


class BearerUnauthorized(Unauthorized):
    def __init__(self, description: str) -> None:
        super().__init__(
            description, www_authenticate=WWWAuthenticate("bearer", {"realm": "amazing-agent"})
        )


def require_bearer_token() -> None:
    """Runs before routing's result is used, so a refused request touches nothing."""
    path = request.path
    if path != PROTECTED_PREFIX and not path.startswith(PROTECTED_PREFIX + "/"):
        return
    header = request.headers.get("Authorization", "")
    scheme, _, presented = header.strip().partition(" ")
    if scheme.lower() != "bearer" or not presented.strip():
        raise BearerUnauthorized("Missing bearer token: send 'Authorization: Bearer <token>'.")
    # Digests compared in constant time, each of them (several during a rotation): the agent
    # may hold only digests, never a usable token. surrogatepass: a header may carry any
    # character.
    digest = hashlib.sha256(presented.strip().encode("utf-8", "surrogatepass")).digest()
    config = get_runtime().config
    if _matches(digest, config.accepted_token_digests):
        return
    if not _matches(digest, config.read_token_digests):
        raise BearerUnauthorized("The bearer token is not valid for this agent.")
    if not read_only_may(request.method, path):
        raise Forbidden("This token may only read (and stop the robot).")


def _matches(digest: bytes, accepted: tuple[bytes, ...]) -> bool:
    # Every digest compared, none skipped: the time taken does not say which one matched.
    return sum(hmac.compare_digest(digest, expected) for expected in accepted) > 0
