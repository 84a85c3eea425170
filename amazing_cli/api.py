"""The portal's public REST API, as the CLI calls it.

Every call names one operation of :data:`OPERATIONS` (method and path template, exactly as
``/api/schema/`` lists them; a test holds the two together). Errors come back in the API's one
envelope and become a :class:`~amazing_cli.errors.CliError` with the exit code of their kind.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from typing import Any

import requests
from requests.adapters import HTTPAdapter
from urllib3.util.retry import Retry

from amazing_cli.errors import BAD_INPUT, NOT_FOUND, REFUSED, UNAVAILABLE, CliError

OPERATIONS: dict[str, tuple[str, str]] = {
    "me": ("GET", "/api/v1/me/"),
    "token_sign_in": ("POST", "/api/v1/auth/token/"),
    "token_revoke": ("DELETE", "/api/v1/auth/token/"),
    "resources": ("GET", "/api/v1/resources/"),
    "availability": ("GET", "/api/v1/resources/{name}/availability/"),
    "quota": ("GET", "/api/v1/quota/"),
    "experiments": ("GET", "/api/v1/experiments/"),
    "experiment_create": ("POST", "/api/v1/experiments/"),
    "experiment": ("GET", "/api/v1/experiments/{id}/"),
    "reservation_create": ("POST", "/api/v1/reservations/"),
    "reservation_check": ("POST", "/api/v1/reservations/check/"),
    "reservation_cancel": ("DELETE", "/api/v1/reservations/{id}/"),
    "reservation_attach": ("POST", "/api/v1/reservations/{id}/attach/"),
    "runs": ("GET", "/api/v1/runs/"),
    "run": ("GET", "/api/v1/runs/{id}/"),
    "samples_csv": ("GET", "/api/v1/runs/{id}/samples.csv"),
    "samples_json": ("GET", "/api/v1/runs/{id}/samples.json"),
    "run_package": ("GET", "/api/v1/runs/{id}/package.zip"),
    "samples_parquet": ("GET", "/api/v1/runs/{id}/samples.parquet"),
    "measurement_parquet": ("GET", "/api/v1/runs/{id}/measurements/{name}/points.parquet"),
    "run_again": ("POST", "/api/v1/runs/{id}/again/"),
    "events": ("GET", "/api/v1/events/"),
    "queue": ("GET", "/api/v1/queue/"),
    "queue_create": ("POST", "/api/v1/queue/"),
    "queue_cancel": ("DELETE", "/api/v1/queue/{id}/"),
    "campaign_create": ("POST", "/api/v1/campaigns/"),
    "campaign": ("GET", "/api/v1/campaigns/{id}/"),
    "campaign_cancel": ("POST", "/api/v1/campaigns/{id}/cancel/"),
    "campaign_pause": ("POST", "/api/v1/campaigns/{id}/pause/"),
    "campaign_resume": ("POST", "/api/v1/campaigns/{id}/resume/"),
    "campaign_results": ("GET", "/api/v1/campaigns/{id}/results/"),
    "campaign_package": ("GET", "/api/v1/campaigns/{id}/package.zip"),
    "webhooks": ("GET", "/api/v1/webhooks/"),
    "webhook_create": ("POST", "/api/v1/webhooks/"),
    "webhook": ("GET", "/api/v1/webhooks/{id}/"),
    "webhook_delete": ("DELETE", "/api/v1/webhooks/{id}/"),
    "webhook_test": ("POST", "/api/v1/webhooks/{id}/test/"),
    "webhook_resume": ("POST", "/api/v1/webhooks/{id}/resume/"),
    "webhook_deliveries": ("GET", "/api/v1/webhooks/{id}/deliveries/"),
    "measurements": ("GET", "/api/v1/runs/{id}/measurements/"),
    "measurement_upload": ("POST", "/api/v1/runs/{id}/measurements/"),
    "measurement": ("GET", "/api/v1/runs/{id}/measurements/{name}/"),
    "measurement_offset": ("PATCH", "/api/v1/runs/{id}/measurements/{name}/"),
    "measurement_delete": ("DELETE", "/api/v1/runs/{id}/measurements/{name}/"),
    "schema": ("GET", "/api/schema/"),
}

CONNECT_TIMEOUT_S = 5.0
READ_TIMEOUT_S = 30.0
USER_AGENT = "amazing-cli/1"
CLIENT_HEADER = "X-Amazing-Client"


def _exit_code(status: int) -> int:
    if status in (400, 422):
        return BAD_INPUT
    if status in (401, 403, 409, 429):
        return REFUSED
    if status == 404:
        return NOT_FOUND
    return UNAVAILABLE


def _error_code(response: requests.Response) -> str | None:
    try:
        body = response.json()
    except ValueError:
        return None
    return str(body["error"]) if isinstance(body, dict) and "error" in body else None


def _message(response: requests.Response) -> str:
    """The envelope's detail, and each field's messages that say more, on one line."""
    try:
        body = response.json()
    except ValueError:
        body = None
    if not isinstance(body, dict) or "detail" not in body:
        return f"the portal answered {response.status_code} {response.reason}"
    detail = str(body["detail"])
    parts = [detail]
    fields = body.get("fields")
    if isinstance(fields, dict):
        for name, messages in fields.items():
            for message in messages if isinstance(messages, list) else [messages]:
                if str(message) not in detail:
                    parts.append(f"{name}: {message}")
    return " ".join(p.rstrip() for p in parts).replace("\n", " ")


class Api:
    """A session with the portal at ``url``, authenticated by ``token``."""

    def __init__(self, url: str, token: str | None) -> None:
        self.url = url.rstrip("/")
        self.session = requests.Session()
        self.session.headers["User-Agent"] = USER_AGENT
        self.session.headers["Accept"] = "application/json"
        # Which door a change came through, for the audit log (the portal's ``Channel``).
        self.session.headers[CLIENT_HEADER] = "cli"
        if token:
            self.session.headers["Authorization"] = f"Token {token}"
        # Connection failures are retried (nothing reached the portal), and 429 after the
        # Retry-After it gives; a request that reached the portal is never sent twice.
        retry = Retry(
            total=4,
            connect=2,
            read=0,
            status=3,
            status_forcelist=[429],
            allowed_methods=None,
            backoff_factor=0.5,
            respect_retry_after_header=True,
            raise_on_status=False,
        )
        adapter = HTTPAdapter(max_retries=retry)
        self.session.mount("http://", adapter)
        self.session.mount("https://", adapter)

    def _send(
        self,
        operation: str,
        *,
        path: dict[str, Any] | None = None,
        params: dict[str, Any] | None = None,
        json: Any = None,
        data: dict[str, Any] | None = None,
        files: dict[str, Any] | None = None,
        headers: dict[str, str] | None = None,
        stream: bool = False,
    ) -> requests.Response:
        method, template = OPERATIONS[operation]
        url = self.url + template.format(**(path or {}))
        try:
            response = self.session.request(
                method,
                url,
                params=params,
                json=json,
                data=data,
                files=files,
                headers=headers,
                stream=stream,
                timeout=(CONNECT_TIMEOUT_S, READ_TIMEOUT_S),
            )
        except requests.exceptions.RequestException as exc:
            reason = exc.__class__.__name__
            if isinstance(exc, requests.exceptions.ConnectionError):
                reason = "connection refused or host unreachable"
            elif isinstance(exc, requests.exceptions.Timeout):
                reason = "no answer in time"
            raise CliError(
                f"cannot reach the portal at {self.url}: {reason}", exit_code=UNAVAILABLE
            ) from exc
        if response.status_code >= 400:
            message = _message(response)
            response.close()
            raise CliError(
                message,
                exit_code=_exit_code(response.status_code),
                status=response.status_code,
                error=_error_code(response),
            )
        return response

    def call(self, operation: str, **kwargs: Any) -> Any:
        """The JSON answer of one operation (None for an answer without a body)."""
        response = self._send(operation, **kwargs)
        if response.status_code == 204:
            return None
        try:
            return response.json()
        except ValueError as exc:
            raise CliError(
                f"the portal at {self.url} did not answer JSON; is it the AMazING portal?",
                exit_code=UNAVAILABLE,
            ) from exc

    def create(
        self,
        operation: str,
        body: dict[str, Any] | None = None,
        *,
        key: str | None = None,
        **kwargs: Any,
    ) -> Any:
        """A creating POST, safe to retry: the portal replays the answer to a repeated key.

        ``key``: the ``X-Idempotency-Key`` to send (a fresh one by default); a script that
        retries a POST whose answer it lost sends the same key again."""
        key = key or f"amazing-cli-{uuid.uuid4()}"
        return self.call(operation, json=body, headers={"X-Idempotency-Key": key}, **kwargs)

    def pages(
        self,
        operation: str,
        *,
        path: dict[str, Any] | None = None,
        params: dict[str, Any] | None = None,
        limit: int | None = None,
    ) -> Iterator[dict[str, Any]]:
        """Every item of a paginated list (at most ``limit``), following ``next``."""
        query = dict(params or {})
        query.setdefault("limit", 100 if limit is None else min(limit, 500))
        query["offset"] = 0
        given = 0
        while True:
            page = self.call(operation, path=path, params=query)
            for item in page["results"]:
                if limit is not None and given >= limit:
                    return
                given += 1
                yield item
            if not page.get("next") or not page["results"]:
                return
            query["offset"] += len(page["results"])

    def stream(self, operation: str, **kwargs: Any) -> requests.Response:
        """A streamed answer (downloads); the caller closes it."""
        return self._send(operation, stream=True, **kwargs)

    def schema(self) -> dict[str, Any]:
        """The OpenAPI description the portal serves."""
        answer = self.call("schema", headers={"Accept": "application/json"})
        if not isinstance(answer, dict) or "components" not in answer:
            raise CliError(
                f"the portal at {self.url} serves no OpenAPI description", exit_code=UNAVAILABLE
            )
        return answer
