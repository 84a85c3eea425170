"""Which (method, path) pairs an OpenAPI document allows: the CLI may call no others."""

from __future__ import annotations

import re
from collections.abc import Iterable
from urllib.parse import urlsplit

ACCESS_LOG_REQUEST = re.compile(r'"([A-Z]+) (\S+) HTTP/[\d.]+"')
METHODS = {"get", "put", "post", "delete", "patch", "head", "options", "trace"}


def documented(schema: dict) -> list[tuple[str, re.Pattern[str]]]:
    found = []
    for template, item in schema["paths"].items():
        pattern = re.escape(template)
        pattern = re.sub(r"\\\{[^}]+\\\}", "[^/]+", pattern)
        for method in item:
            if method in METHODS:
                found.append((method.upper(), re.compile(f"^{pattern}$")))
    return found


def undocumented(calls: Iterable[tuple[str, str]], schema: dict) -> list[tuple[str, str]]:
    """The calls (method, URL or path) that no operation of ``schema`` describes."""
    operations = documented(schema)
    missing = []
    for method, url in calls:
        path = urlsplit(url).path
        if not any(method == m and p.match(path) for m, p in operations):
            missing.append((method, path))
    return sorted(set(missing))


def requests_in_access_log(lines: Iterable[str]) -> list[tuple[str, str]]:
    """(method, path) of each request the ASGI server logged."""
    return [(m[1], m[2]) for line in lines if (m := ACCESS_LOG_REQUEST.search(line))]
