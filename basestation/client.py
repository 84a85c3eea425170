"""REST client for the base-station agent (what the portal's Celery tasks use).

Plain ``requests``; no Django. Every failure is an :class:`AgentError` whose ``retryable``
says whether trying again later can help: connection errors, timeouts and 5xx can;
4xx cannot (the request itself is wrong, or conflicts with the agent's state).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from datetime import date
from typing import Any
from urllib.parse import quote

import requests

from basestation.contract import REQUEST_ID_HEADER, STOP_PATH, request_id_or_new

API_PREFIX = "/api/v1"
# A stop's reason is sent cut to this: the agent keeps less (and says so in its answer), and
# no reason can make the body too large for the agent to read.
MAX_STOP_REASON_SENT_CHARS = 1000


class AgentError(Exception):
    def __init__(
        self,
        message: str,
        *,
        retryable: bool,
        status: int | None,
        body: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.retryable = retryable
        self.status = status
        self.body = body or {}


class AgentUnauthorized(AgentError):
    """401: the token is wrong or missing (fix the configuration, do not retry)."""


class AgentNotFound(AgentError):
    """404: no such run on the agent."""


class AgentConflict(AgentError):
    """409: the request contradicts the agent's state.

    ``kind`` is the agent's ``conflict`` field: ``body_differs``, ``window_overlaps``,
    ``already_ended`` (runs), ``robot_busy`` or ``estop_latched`` (manual control).
    """

    @property
    def kind(self) -> str | None:
        value = self.body.get("conflict")
        return value if isinstance(value, str) else None


class AgentRejected(AgentError):
    """422: the agent refused the request; ``fields`` maps field names to messages."""

    @property
    def fields(self) -> dict[str, list[str]]:
        value = self.body.get("fields")
        return value if isinstance(value, dict) else {}


_BY_STATUS: dict[int, type[AgentError]] = {
    401: AgentUnauthorized,
    404: AgentNotFound,
    409: AgentConflict,
    422: AgentRejected,
}


class AgentClient:
    def __init__(
        self,
        base_url: str,
        token: str,
        timeout_s: float = 5.0,
        *,
        request_id: Callable[[], str | None] | None = None,
    ) -> None:
        """``base_url`` is the agent's root, e.g. ``http://10.0.0.5:8700`` (no ``/api/v1``).

        ``request_id`` gives the id of the work under way (the portal's request or task),
        sent with every call as ``X-Request-ID`` so that the agent's log line names it; a
        call made outside any (or without ``request_id``) gets an id of its own.
        """
        self.base_url = base_url.rstrip("/")
        self.timeout_s = timeout_s
        self._request_id = request_id
        self._session = requests.Session()
        self._session.headers["Authorization"] = f"Bearer {token}"
        self._session.headers["Accept"] = "application/json"

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> AgentClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- endpoints -------------------------------------------------------------------------

    def healthz(self) -> dict[str, Any]:
        return self._request("GET", "/healthz")

    def status(self) -> dict[str, Any]:
        return self._request("GET", f"{API_PREFIX}/status")

    def rail(self) -> dict[str, Any]:
        """The rail drawn for a map (``GET /rail``)."""
        return self._request("GET", f"{API_PREFIX}/rail")

    def list_runs(self, state: str | None = None) -> list[dict[str, Any]]:
        params = {"state": state} if state else None
        runs = self._request("GET", f"{API_PREFIX}/runs", params=params)["runs"]
        assert isinstance(runs, list)
        return runs

    def put_run(self, run_id: str, body: dict[str, Any]) -> dict[str, Any]:
        """Stage ``run_id`` (idempotent: the same body again returns the stored run)."""
        return self._request("PUT", self._run_path(run_id), json=body)

    def get_run(self, run_id: str) -> dict[str, Any]:
        return self._request("GET", self._run_path(run_id))

    def delete_run(self, run_id: str) -> dict[str, Any]:
        """Cancel a staged run or abort a running one; returns the run in its new state."""
        return self._request("DELETE", self._run_path(run_id))

    def battery(self) -> dict[str, Any]:
        """``{"filtered_v", "raw_v", "window", "age_s", "low_battery_v", "low"}``."""
        return self._request("GET", f"{API_PREFIX}/battery")

    def control(
        self,
        *,
        user: str,
        velocity_mps: float,
        direction: str,
        ttl_s: float | None = None,
        force: bool = False,
    ) -> dict[str, Any]:
        """Manual drive (admins): hold the velocity for ``ttl_s`` (agent default 1 s).
        Returns ``{"manual": {...} | None, "aborted_run": id | None, "clock": s,
        "robot": {...}, "link": {...}}`` (the last two as in :meth:`status`)."""
        body: dict[str, Any] = {
            "user": user,
            "velocity_mps": velocity_mps,
            "direction": direction,
            "force": force,
        }
        if ttl_s is not None:
            body["ttl_s"] = ttl_s
        return self._request("POST", f"{API_PREFIX}/control", json=body)

    def stop(self, *, user: str | None = None, reason: str | None = None) -> dict[str, Any]:
        """Latch the emergency stop; returns ``{"estop": {...}, "aborted_run": ...,
        "truncated": [...], "ignored": [...]}``. The agent serves it ahead of every other
        request and refuses it only for the token."""
        if reason is not None:
            reason = reason[:MAX_STOP_REASON_SENT_CHARS]
        body = {k: v for k, v in (("user", user), ("reason", reason)) if v is not None}
        return self._request("POST", STOP_PATH, json=body)

    def release_stop(self, *, user: str | None = None) -> dict[str, Any]:
        """Release the emergency stop; returns ``{"estop": {...}, "released": bool}``."""
        body = {"user": user} if user is not None else {}
        return self._request("POST", f"{API_PREFIX}/stop/release", json=body)

    def day_log(self, day: date) -> dict[str, Any]:
        """The usage log of one UTC day: ``{"date", "timezone", "entries": [...]}``."""
        return self._request("GET", f"{API_PREFIX}/logs/{day.isoformat()}")

    def samples(
        self, run_id: str, after_seq: int = 0, limit: int = 1000, wait_s: int = 0
    ) -> dict[str, Any]:
        """One page: ``{"run_id", "state", "samples", "last_seq", "more"}``.

        ``wait_s`` > 0 long-polls: with nothing after ``after_seq`` yet and the run staged or
        running, the agent answers when the next samples are stored or the run changes
        state, at the latest after ``wait_s`` (the request's timeout grows by as much).
        """
        params = {"after": after_seq, "limit": limit}
        if wait_s:
            params["wait_s"] = wait_s
        return self._request(
            "GET",
            f"{self._run_path(run_id)}/samples",
            params=params,
            timeout=self.timeout_s + wait_s,
        )

    def iter_samples(
        self, run_id: str, after_seq: int = 0, limit: int = 1000
    ) -> Iterator[dict[str, Any]]:
        """Every sample after ``after_seq``, paging until the agent says there is no more."""
        while True:
            page = self.samples(run_id, after_seq, limit)
            yield from page["samples"]
            if not page["more"] or page["last_seq"] <= after_seq:
                return
            after_seq = page["last_seq"]

    # -- plumbing ----------------------------------------------------------------------------

    @staticmethod
    def _run_path(run_id: str) -> str:
        return f"{API_PREFIX}/runs/{quote(run_id, safe='')}"

    def _request(
        self, method: str, path: str, *, timeout: float | None = None, **kwargs: Any
    ) -> dict[str, Any]:
        url = self.base_url + path
        current = self._request_id() if self._request_id is not None else None
        headers = {REQUEST_ID_HEADER: request_id_or_new(current)}
        try:
            response = self._session.request(
                method, url, timeout=timeout or self.timeout_s, headers=headers, **kwargs
            )
        except (
            requests.ConnectionError,
            requests.Timeout,
            requests.exceptions.ChunkedEncodingError,
        ) as exc:
            raise AgentError(
                f"{method} {url}: {exc.__class__.__name__}: {exc}", retryable=True, status=None
            ) from exc
        except requests.RequestException as exc:
            raise AgentError(
                f"{method} {url}: {exc.__class__.__name__}: {exc}", retryable=False, status=None
            ) from exc
        try:
            payload = response.json()
        except ValueError:
            payload = None
        body = payload if isinstance(payload, dict) else None
        if response.ok:
            if body is None:
                raise AgentError(
                    f"{method} {url}: answer is not a JSON object",
                    retryable=False,
                    status=response.status_code,
                )
            return body
        detail = ""
        if body is not None:
            detail = str(body.get("detail") or body.get("error") or "")
        message = f"{method} {url}: HTTP {response.status_code}" + (f": {detail}" if detail else "")
        error_class = _BY_STATUS.get(response.status_code, AgentError)
        raise error_class(
            message,
            retryable=response.status_code >= 500,
            status=response.status_code,
            body=body,
        )
