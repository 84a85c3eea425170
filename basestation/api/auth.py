"""Bearer-token check for every ``/api/v1`` request."""

from __future__ import annotations

import hashlib
import hmac

from flask import request
from werkzeug.datastructures import WWWAuthenticate
from werkzeug.exceptions import Unauthorized

from basestation.runtime import get_runtime

PROTECTED_PREFIX = "/api/v1"


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
    accepted = get_runtime().config.accepted_token_digests
    if not sum(hmac.compare_digest(digest, expected) for expected in accepted):
        raise BearerUnauthorized("The bearer token is not valid for this agent.")
