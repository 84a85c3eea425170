"""Each robot's agent token, kept by the portal: issue, rotate, revoke, and read for a call.

The portal presents the token (``Authorization: Bearer …``), so it must hold the token itself;
the agent holds only SHA-256 digests (``AGENT_TOKEN_SHA256``). The token is stored in the
database, encrypted with Fernet (``cryptography``) under a key derived from
``DJANGO_SECRET_KEY``: every portal process (web, workers, collector, beat) reads the
current token at its next call to the agent, so issuing and rotating need no restart of the
portal, and a database dump (backups leave the server) does not contain a usable token.
``DJANGO_SECRET_KEY_FALLBACKS`` still decrypts tokens stored under a previous secret key.

A robot without a stored token falls back to the environment (``AGENT_TOKEN`` and
``AGENT_TOKENS``, named by ``Resource.agent_token_name``), as deployments did before.

Rotation without a refused call: ``agent_token_rotate`` stores a next token beside the
current one, which the portal still presents; the agent is given both digests and
restarted; ``agent_token_rotation_finish`` makes the portal present the next token; then the
old digest is removed from the agent.
"""

from __future__ import annotations

import base64
import hashlib
import secrets
from dataclasses import dataclass

from cryptography.fernet import Fernet, InvalidToken, MultiFernet
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.kdf.hkdf import HKDF
from django.conf import settings
from django.db import transaction
from django.utils import timezone

from bookings.choices import ResourceKind
from bookings.models import AgentCredential, Resource

TOKEN_BYTES = 32
# Binds the derived key to this one purpose: the same secret key derives other keys elsewhere.
_KEY_INFO = b"amazing agent tokens v1"


class AgentTokenError(Exception):
    """The request does not fit the robot's tokens (no such robot, no rotation under way…)."""


class AgentTokenUnreadable(Exception):
    """A stored token cannot be decrypted: the secret key changed without its fallback."""


@dataclass(frozen=True)
class AgentTokens:
    """A robot's tokens as an operator needs them: the digests its agent must accept."""

    robot: str
    current_sha256: str
    next_sha256: str | None

    @property
    def agent_digests(self) -> tuple[str, ...]:
        """What ``AGENT_TOKEN_SHA256`` on the robot's base station must list now."""
        if self.next_sha256 is None:
            return (self.current_sha256,)
        return (self.current_sha256, self.next_sha256)


def token_sha256(token: str) -> str:
    """The digest the agent keeps (``basestation/config.py`` compares the same)."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _fernet_key(secret: str) -> bytes:
    key = HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=_KEY_INFO).derive(
        secret.encode("utf-8")
    )
    return base64.urlsafe_b64encode(key)


def _cipher() -> MultiFernet:
    # The first key encrypts; every key decrypts (a changed secret key, its old one kept in
    # the fallbacks, still reads what was stored before).
    secrets_in_use = [settings.SECRET_KEY, *getattr(settings, "SECRET_KEY_FALLBACKS", [])]
    return MultiFernet([Fernet(_fernet_key(secret)) for secret in secrets_in_use])


def _encrypt(token: str) -> str:
    return _cipher().encrypt(token.encode("utf-8")).decode("ascii")


def _decrypt(ciphertext: str) -> str:
    try:
        return _cipher().decrypt(ciphertext.encode("ascii")).decode("utf-8")
    except InvalidToken:
        # Phrased to follow the robot's name ("mobile-1 has …").
        raise AgentTokenUnreadable(
            "has a stored agent token that cannot be decrypted: DJANGO_SECRET_KEY changed "
            "(keep the old one in DJANGO_SECRET_KEY_FALLBACKS) or the row was altered"
        ) from None


def _robot(name: str) -> Resource:
    resource = Resource.objects.filter(name=name, kind=ResourceKind.MOBILE).first()
    if resource is None:
        raise AgentTokenError(f"no robot named {name!r}")
    return resource


def _tokens(resource: Resource, credential: AgentCredential) -> AgentTokens:
    next_token = (
        _decrypt(credential.next_token_encrypted) if credential.next_token_encrypted else None
    )
    return AgentTokens(
        robot=resource.name,
        current_sha256=token_sha256(_decrypt(credential.token_encrypted)),
        next_sha256=None if next_token is None else token_sha256(next_token),
    )


def _new_token() -> str:
    return secrets.token_urlsafe(TOKEN_BYTES)


# -- reads ------------------------------------------------------------------------------------


def agent_token_stored(resource: Resource) -> str | None:
    """The token the portal presents to ``resource``'s agent now, or None when none is
    stored (the environment's then applies). Read at every call: a rotation finished in
    another process takes effect at the next call here."""
    ciphertext = (
        AgentCredential.objects.filter(resource_id=resource.pk)
        .values_list("token_encrypted", flat=True)
        .first()
    )
    return None if ciphertext is None else _decrypt(ciphertext)


def agent_tokens_show(*, robot: str) -> AgentTokens | None:
    resource = _robot(robot)
    credential = AgentCredential.objects.filter(resource=resource).first()
    return None if credential is None else _tokens(resource, credential)


# -- writes -----------------------------------------------------------------------------------


def agent_token_issue(*, robot: str, token: str | None = None) -> AgentTokens:
    """Store a first token for ``robot`` (a new random one, or ``token``: the one its agent
    already accepts, when moving it from the environment). Refuses a robot that has one:
    that is a rotation."""
    with transaction.atomic():
        resource = Resource.objects.select_for_update().get(pk=_robot(robot).pk)
        if AgentCredential.objects.filter(resource=resource).exists():
            raise AgentTokenError(
                f"{robot} already has a stored agent token: rotate it, or revoke it first"
            )
        credential = AgentCredential.objects.create(
            resource=resource,
            token_encrypted=_encrypt(token or _new_token()),
            issued_at=timezone.now(),
        )
        return _tokens(resource, credential)


def agent_token_rotate(*, robot: str) -> AgentTokens:
    """Start a rotation: a next token beside the current one, which stays in use."""
    with transaction.atomic():
        resource = Resource.objects.select_for_update().get(pk=_robot(robot).pk)
        credential = AgentCredential.objects.filter(resource=resource).first()
        if credential is None:
            raise AgentTokenError(f"{robot} has no stored agent token: issue one first")
        if credential.next_token_encrypted:
            raise AgentTokenError(
                f"a rotation of {robot}'s token is already under way: finish it first"
            )
        credential.next_token_encrypted = _encrypt(_new_token())
        credential.rotation_started_at = timezone.now()
        credential.save(update_fields=["next_token_encrypted", "rotation_started_at"])
        return _tokens(resource, credential)


def agent_token_rotation_finish(*, robot: str) -> AgentTokens:
    """The portal presents the next token from now on; the old one is forgotten."""
    with transaction.atomic():
        resource = Resource.objects.select_for_update().get(pk=_robot(robot).pk)
        credential = AgentCredential.objects.filter(resource=resource).first()
        if credential is None or not credential.next_token_encrypted:
            raise AgentTokenError(f"no rotation of {robot}'s token is under way")
        credential.token_encrypted = credential.next_token_encrypted
        credential.next_token_encrypted = ""
        credential.issued_at = timezone.now()
        credential.rotation_started_at = None
        credential.save(
            update_fields=[
                "token_encrypted",
                "next_token_encrypted",
                "issued_at",
                "rotation_started_at",
            ]
        )
        return _tokens(resource, credential)


def agent_token_revoke(*, robot: str) -> AgentTokens | None:
    """Forget ``robot``'s stored tokens; returns the digests to remove from its agent (None
    when they can no longer be read: the token goes all the same)."""
    with transaction.atomic():
        resource = Resource.objects.select_for_update().get(pk=_robot(robot).pk)
        credential = AgentCredential.objects.filter(resource=resource).first()
        if credential is None:
            raise AgentTokenError(f"{robot} has no stored agent token")
        try:
            tokens: AgentTokens | None = _tokens(resource, credential)
        except AgentTokenUnreadable:
            tokens = None
        credential.delete()
        return tokens


def agent_token_from_environment(*, robot: str) -> str:
    """The token the environment gives ``robot`` (``AGENT_TOKEN``/``AGENT_TOKENS`` by its
    token name), to store it unchanged: the agent's configuration need not change."""
    resource = _robot(robot)
    name = resource.agent_token_name or "default"
    token = settings.AGENT_TOKENS.get(name)
    if not token:
        raise AgentTokenError(f"the environment has no agent token named {name!r} for {robot}")
    return token
