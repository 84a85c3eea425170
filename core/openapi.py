"""The OpenAPI description of the public API: every answer an operation can give.

drf-spectacular describes the successful answers from each view's serializers; this module
adds the rest, the same way for every operation, so that the schema states what the server
does (a test runs schemathesis against a live server to hold it to that):

- 400 with the error envelope and its field errors, when the operation takes input;
- 401 with ``WWW-Authenticate: Token`` for missing or refused credentials;
- 403 when the user may not do it;
- 404 when the path names something (or the user may not see it);
- 409 and 422 where ``X-Idempotency-Key`` applies (a duplicate still in flight, a key reused
  for another request), with the header itself and ``Idempotent-Replayed`` on replays;
- 413 when the operation takes a body and the body is over the size limit;
- 429 with ``Retry-After`` from the throttles;
- whatever a view adds with :func:`errors` (409 for conflicts, 503 when a base station or
  the scheduler does not answer).
"""

from __future__ import annotations

from typing import Any

from drf_spectacular import openapi
from drf_spectacular.utils import OpenApiResponse
from rest_framework import permissions, serializers

from core.api import GreaterThan
from core.events.catalogue import PAYLOADS

DESCRIPTION = """\
Experiments, reservations, runs and their measurements on the AMazING testbed's mobile node.

**Authentication.** Send `Authorization: Token <key>`: make one on the portal's *API tokens*
page (`/account/tokens/`), or let `amazing login` make and store yours. A request without
valid credentials gets 401 with `WWW-Authenticate: Token`. The portal's own pages call the
same API with their session cookie and CSRF token; that is not meant for other clients.

**Errors.** Every error has one JSON envelope: `{"error": code, "detail": message}`, and
`"fields": {"path.to.field": [messages]}` when input was at fault (nested fields as dotted
paths, list items by index: `segments.0.velocity_mps`). Codes include `invalid`,
`parse_error`, `not_authenticated`, `authentication_failed`, `permission_denied`,
`forbidden`, `not_found`, `method_not_allowed`, `conflict`, `quota_exceeded`,
`idempotency_key_reused`, `request_entity_too_large`, `throttled` and `agent_unavailable`.
Unknown paths under `/api/` answer 404 in the same envelope; a body over the size limit
(2.5 MiB) answers 413, its detail naming the limit.

**Throttling.** Authenticated clients are limited per user and anonymous ones per address
(`API_THROTTLE_USER`, `API_THROTTLE_ANON`; refused credentials count as anonymous). Over the
limit: 429 with `Retry-After` in seconds.

**Pagination.** Lists that grow (experiments, reservations, runs, blackouts, quota policies,
audit events) take `limit` (1–500, default 100) and `offset`, and answer
`{"count", "next", "previous", "results"}`; follow `next` until it is null.

**Idempotency.** `POST /api/v1/reservations/` takes `X-Idempotency-Key`: the same key with the
same body replays the first answer (`Idempotent-Replayed: true`), with another body answers
422, and while the first is still being handled answers 409.
"""


class ErrorEnvelope(serializers.Serializer):
    """Every error answer of the API."""

    error = serializers.CharField(help_text="A stable code, e.g. `invalid` or `not_found`.")
    detail = serializers.CharField(help_text="What went wrong, for a person.")
    # DRF takes the declared field out of the class, so the name does not hide ``.fields``.
    fields = serializers.DictField(  # type: ignore[assignment]
        child=serializers.ListField(child=serializers.CharField()),
        required=False,
        help_text="Input at fault: each field (dotted path for nested ones) with its messages.",
    )


_ERROR_DESCRIPTIONS = {
    400: "Invalid input: `fields` names each field at fault.",
    401: "No credentials, or refused ones.",
    403: "Not allowed for this user.",
    404: "Not found, or not visible to this user.",
    409: "Conflicts with the current state.",
    413: "The request body is over the size limit; `detail` names it.",
    422: "`X-Idempotency-Key` was used for a different request.",
    429: "Too many requests; retry after `Retry-After` seconds.",
    503: "A part the answer depends on (a base station or the scheduler) did not answer.",
}

_HEADERS = {
    401: {
        "WWW-Authenticate": {
            "required": True,
            "description": "How to authenticate: `Token`.",
            "schema": {"type": "string"},
        }
    },
    429: {
        "Retry-After": {
            "required": True,
            "description": "Seconds to wait before trying again.",
            "schema": {"type": "integer", "minimum": 1},
        }
    },
}


def errors(*codes: int, **descriptions: str) -> dict[int, OpenApiResponse]:
    """Error answers for ``extend_schema(responses=…)``; ``e409="why"`` words one of them."""
    return {
        code: OpenApiResponse(
            ErrorEnvelope,
            description=descriptions.get(f"e{code}", _ERROR_DESCRIPTIONS.get(code, "")),
        )
        for code in codes
    }


class ClosedSerializer(serializers.Serializer):
    """An input object that refuses keys it does not know (``additionalProperties: false``)."""

    def to_internal_value(self, data: Any) -> Any:
        if isinstance(data, dict):
            unknown = sorted(set(data) - set(self.fields))
            if unknown:
                raise serializers.ValidationError(
                    {key: ["Not a field of this object."] for key in unknown}
                )
        return super().to_internal_value(data)


class AutoSchema(openapi.AutoSchema):
    def get_serializer_name(self, serializer: Any, direction: Any) -> str:
        # ExperimentOutput → Experiment, ExperimentInput → ExperimentRequest: the names a
        # generated client shows.
        name: str = super().get_serializer_name(serializer, direction)
        for suffix in ("Output", "Input"):
            if name.endswith(suffix) and len(name) > len(suffix):
                return name[: -len(suffix)]
        return name

    def get_tags(self) -> list[str]:
        # /api/v1/runs/{id}/samples/ → "runs": one group per resource in the docs.
        parts = [p for p in self.path.split("/") if p and not p.startswith("{")]
        return [parts[2]] if len(parts) > 2 and parts[:2] == ["api", "v1"] else ["api"]

    def _map_basic_serializer(self, serializer: Any, direction: Any) -> dict[str, Any]:
        schema: dict[str, Any] = super()._map_basic_serializer(serializer, direction)
        if direction == "request" and isinstance(serializer, ClosedSerializer):
            schema["additionalProperties"] = False
        return schema

    def _map_serializer_field(
        self, field: Any, direction: Any, bypass_extensions: bool = False
    ) -> dict[str, Any]:
        schema: dict[str, Any] = super()._map_serializer_field(field, direction, bypass_extensions)
        if (
            direction == "request"
            and isinstance(field, serializers.CharField)
            and schema.get("type") == "string"
            and "pattern" not in schema
            and "format" not in schema
        ):
            if isinstance(field, serializers.SlugField):
                # A slug says so (a name by which rows are found, in the request's data or
                # its query), never with DRF's text pattern in its place.
                schema["pattern"] = "^[-\\w]+$" if field.allow_unicode else "^[-a-zA-Z0-9_]+$"
                return schema
            # What DRF refuses in text: NUL characters, and (unless blank is allowed) text
            # that is only whitespace, which it trims to nothing.
            if field.allow_blank or not field.trim_whitespace:
                schema["pattern"] = "^[^\\u0000]*$"
            else:
                schema["pattern"] = "^[^\\u0000]*[^\\s\\u0000][^\\u0000]*$"
        return schema

    def _insert_field_validators(self, field: Any, schema: dict[str, Any]) -> None:
        super()._insert_field_validators(field, schema)
        for validator in field.validators:
            if isinstance(validator, GreaterThan):
                schema["minimum"] = validator.limit
                schema["exclusiveMinimum"] = True

    def _idempotent(self) -> bool:
        handler = getattr(self.view, self.method.lower(), None)
        return bool(getattr(handler, "idempotency_key", False))

    def _requires_authentication(self) -> bool:
        return not any(isinstance(p, permissions.AllowAny) for p in self.view.get_permissions())

    def _takes_input(self) -> bool:
        if self._get_request_body() is not None:
            return True
        return any(p["in"] == "query" for p in self._get_parameters())

    def _get_parameters(self) -> list[dict[str, Any]]:
        parameters: list[dict[str, Any]] = super()._get_parameters()
        if self._idempotent():
            parameters.append(
                {
                    "in": "header",
                    "name": "X-Idempotency-Key",
                    "required": False,
                    "description": "Any printable text up to 128 characters, new for each "
                    "request; sending the request again with it replays the first answer.",
                    "schema": {
                        "type": "string",
                        "minLength": 1,
                        "maxLength": 128,
                        "pattern": "^[ -~]+$",
                    },
                }
            )
        return parameters

    def _get_response_bodies(self, direction: Any = "response") -> dict[str, Any]:
        responses: dict[str, Any] = super()._get_response_bodies(direction)
        wanted = {429}
        if self._requires_authentication():
            wanted |= {401, 403}
        if self._takes_input():
            wanted.add(400)
        if self._get_request_body() is not None:
            wanted.add(413)
        if "{" in self.path:
            wanted.add(404)
        if self._idempotent():
            wanted |= {400, 409, 422}
            for status, answer in responses.items():
                if status.startswith("2"):
                    answer.setdefault("headers", {})["Idempotent-Replayed"] = {
                        "required": False,
                        "description": "`true` when this is the stored answer to an earlier "
                        "request with the same key.",
                        "schema": {"type": "string", "enum": ["true"]},
                    }
        for code in sorted(wanted):
            if str(code) in responses:
                continue
            response = self._get_response_for_code(
                OpenApiResponse(ErrorEnvelope, description=_ERROR_DESCRIPTIONS[code]),
                str(code),
                media_types=["application/json"],
                direction=direction,
            )
            if code in _HEADERS:
                response["headers"] = dict(_HEADERS[code])
            responses[str(code)] = response
        for header_code, headers in _HEADERS.items():
            if str(header_code) in responses:
                responses[str(header_code)].setdefault("headers", {}).update(headers)
        return dict(sorted(responses.items()))


def oas30(schema: Any) -> Any:
    """A JSON Schema as OpenAPI 3.0 states it: ``"type": [X, "null"]`` is ``X`` and
    ``nullable``. (The catalogue of events is written in JSON Schema, which the tests check
    payloads with.)"""
    if isinstance(schema, list):
        return [oas30(item) for item in schema]
    if not isinstance(schema, dict):
        return schema
    out = {key: oas30(value) for key, value in schema.items()}
    kind = out.get("type")
    if isinstance(kind, list) and "null" in kind:
        [out["type"]] = [k for k in kind if k != "null"]
        out["nullable"] = True
    elif None in out.get("enum", []):
        out["nullable"] = True
    return out


def event_payload_components() -> dict[str, Any]:
    """Each event payload's shape and version, as a component, saying which types carry it."""
    return {
        component: {
            **oas30(schema),
            "description": "The payload of " + ", ".join(f"`{t}`" for t in types) + ".",
        }
        for component, (schema, types) in PAYLOADS.items()
    }


def postprocess_schema(result: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
    result["info"]["description"] = DESCRIPTION
    result.setdefault("components", {}).setdefault("schemas", {}).update(event_payload_components())
    return result
