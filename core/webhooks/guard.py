"""Where a webhook may be sent: checked when it is made and again before every try.

In production only ``https``, and only to public addresses: a name is resolved here and each of
its addresses checked (private, loopback, link-local such as the cloud metadata service,
shared, reserved, multicast: refused), then the connection goes to the address that was
checked, so a name that resolves elsewhere a moment later (DNS rebinding) changes nothing.
Redirects are never followed (``core.webhooks.sender``).
"""

from __future__ import annotations

import ipaddress
import socket
from dataclasses import dataclass
from urllib.parse import urlsplit

from django.conf import settings

IPAddress = ipaddress.IPv4Address | ipaddress.IPv6Address


class Refused(Exception):
    """The URL may not be sent to; the message says why, for its owner."""


@dataclass(frozen=True)
class Target:
    scheme: str
    host: str  # as written in the URL: the Host header and the certificate's name
    port: int
    path: str  # with its query
    address: str  # the checked address the connection goes to


def _public(address: IPAddress) -> bool:
    mapped = getattr(address, "ipv4_mapped", None)
    if mapped is not None:
        address = mapped
    return address.is_global and not address.is_multicast


def _addresses(host: str, port: int) -> list[IPAddress]:
    try:
        return [ipaddress.ip_address(host)]
    except ValueError:
        pass
    try:
        found = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise Refused(f"{host} does not resolve ({exc})") from None
    # The zone of a link-local IPv6 address ("fe80::1%eth0") is not part of the address.
    return [ipaddress.ip_address(str(info[4][0]).split("%", 1)[0]) for info in found]


def webhook_target(
    url: str, *, allow_http: bool | None = None, allow_private: bool | None = None
) -> Target:
    """The checked target of ``url``; raises :class:`Refused` saying why not. Unless told,
    what is allowed comes from the settings (``WEBHOOK_ALLOW_HTTP``,
    ``WEBHOOK_ALLOW_PRIVATE``: both off in production)."""
    if allow_http is None:
        allow_http = settings.WEBHOOK_ALLOW_HTTP
    if allow_private is None:
        allow_private = settings.WEBHOOK_ALLOW_PRIVATE
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise Refused(f"not a URL: {exc}") from None
    schemes = ("https", "http") if allow_http else ("https",)
    if parts.scheme not in schemes:
        raise Refused(f"the URL must start with {' or '.join(s + '://' for s in schemes)}")
    if parts.username is not None or parts.password is not None:
        raise Refused("no user name or password in the URL: the signature proves the sender")
    host = parts.hostname
    if not host:
        raise Refused("the URL has no host")
    port = port or (443 if parts.scheme == "https" else 80)
    addresses = _addresses(host, port)
    if not addresses:
        raise Refused(f"{host} has no address")
    if not allow_private:
        for address in addresses:
            if not _public(address):
                where = host if str(address) == host else f"{host} resolves to {address}, which"
                raise Refused(
                    f"{where} is not a public address (private, loopback, link-local or "
                    "reserved): webhooks go to the internet only"
                )
    path = parts.path or "/"
    if parts.query:
        path = f"{path}?{parts.query}"
    return Target(parts.scheme, host, port, path, str(addresses[0]))
