"""The public API's conventions, in one place: errors, input checks, throttles, pagination.

Every error the API answers has one envelope, ``{"error": code, "detail": message}`` with
``"fields": {"path.to.field": [messages]}`` when input was at fault (nested fields are
flattened to dotted paths, list items by index: ``segments.0.velocity_mps``). Domain errors
(``core.errors``), DRF's own errors, unknown paths under ``/api/``, refused credentials and
bodies over ``DATA_UPLOAD_MAX_MEMORY_SIZE`` (413, the limit named) all answer in it; the
OpenAPI schema states it for every operation (``core.openapi``).

Input is checked as the schema states it: a JSON body's values must already have the schema's
JSON type (DRF alone would take ``"5"`` for a number or ``1`` for ``true``), and query values
must be spelled as the schema's type (``1.0`` is not an integer).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Mapping
from datetime import datetime
from functools import wraps
from typing import Any

from django.conf import settings
from django.core.cache import cache, caches
from django.core.cache.backends.redis import RedisCache
from django.core.exceptions import PermissionDenied as DjangoPermissionDenied
from django.core.exceptions import RequestDataTooBig
from django.core.exceptions import ValidationError as DjangoValidationError
from django.http import Http404, HttpRequest, HttpResponse, JsonResponse, QueryDict
from django.http.response import HttpResponseBase
from django.utils.dateparse import parse_datetime
from django.views.decorators.csrf import csrf_exempt
from rest_framework import exceptions, serializers
from rest_framework.pagination import LimitOffsetPagination
from rest_framework.relations import ManyRelatedField, PrimaryKeyRelatedField, SlugRelatedField
from rest_framework.renderers import JSONRenderer
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.settings import api_settings
from rest_framework.throttling import AnonRateThrottle, UserRateThrottle
from rest_framework.views import exception_handler as drf_exception_handler

from core.accounts.models import User
from core.cache import Generation, cached_answer
from core.errors import Busy, DomainError
from core.http import client_address

INVALID_DETAIL = "The request has invalid fields."
NUL_MESSAGE = "Null characters are not allowed."
# The code the base-station agent gives the same refusal (Werkzeug's name for 413).
BODY_TOO_LARGE = "request_entity_too_large"


# --- Errors ---------------------------------------------------------------------------------


def error_body(code: str, detail: str, fields: Mapping[str, list[str]] | None = None) -> dict:
    body: dict[str, Any] = {"error": code, "detail": detail}
    if fields:
        body["fields"] = dict(fields)
    return body


def flatten_field_errors(errors: Any, prefix: str = "") -> dict[str, list[str]]:
    """DRF's nested error structure as ``{"a.0.b": [messages]}``."""
    if isinstance(errors, Mapping):
        flat: dict[str, list[str]] = {}
        for key, value in errors.items():
            flat.update(flatten_field_errors(value, f"{prefix}.{key}" if prefix else str(key)))
        return flat
    if isinstance(errors, list | tuple):
        messages = [str(e) for e in errors if isinstance(e, str)]
        flat = {prefix or api_settings.NON_FIELD_ERRORS_KEY: messages} if messages else {}
        for index, item in enumerate(errors):
            if isinstance(item, Mapping | list | tuple) and item:
                flat.update(
                    flatten_field_errors(item, f"{prefix}.{index}" if prefix else str(index))
                )
        return flat
    return {prefix or api_settings.NON_FIELD_ERRORS_KEY: [str(errors)]}


def _first_problem(fields: Mapping[str, list[str]]) -> str:
    """The detail of an invalid request: its first problem, so one line says what to fix."""
    for name, messages in fields.items():
        if messages:
            if name == api_settings.NON_FIELD_ERRORS_KEY:
                return messages[0]
            return f"{name}: {messages[0]}"
    return INVALID_DETAIL


def _error_code(exc: exceptions.APIException) -> str:
    codes = exc.get_codes()
    return codes if isinstance(codes, str) else exc.default_code


def _anonymous_over_limit(exc: Exception, context: dict[str, Any]) -> exceptions.Throttled | None:
    """Refused credentials count against the anonymous rate: guessing tokens is throttled too.

    DRF checks throttles only after authentication and permissions, so without this a client
    that is refused (401) would never be throttled.
    """
    request, view = context.get("request"), context.get("view")
    if request is None or view is None:
        return None
    if not isinstance(exc, exceptions.NotAuthenticated | exceptions.AuthenticationFailed):
        return None
    throttle = AnonymousThrottle()
    if throttle.allow_request(request, view):
        return None
    return exceptions.Throttled(wait=throttle.wait())


def body_too_large_detail() -> str:
    limit_bytes = settings.DATA_UPLOAD_MAX_MEMORY_SIZE
    return (
        f"The request body is larger than the API's limit of {limit_bytes} bytes "
        f"({limit_bytes / 2**20:.1f} MiB)."
    )


def exception_handler(exc: Exception, context: dict[str, Any]) -> Response | None:
    if isinstance(exc, DomainError):
        answer = Response(error_body(exc.code, exc.message, exc.fields), status=exc.http_status)
        if isinstance(exc, Busy):
            answer["Retry-After"] = str(exc.retry_after_s)
        return answer
    if isinstance(exc, RequestDataTooBig):
        # Django would answer its HTML 400 page; the limit is DATA_UPLOAD_MAX_MEMORY_SIZE,
        # checked against the declared length before the body is read.
        return Response(error_body(BODY_TOO_LARGE, body_too_large_detail()), status=413)
    if isinstance(exc, DjangoValidationError):
        exc = exceptions.ValidationError(
            exc.message_dict if hasattr(exc, "error_dict") else exc.messages
        )
    elif isinstance(exc, Http404):
        exc = exceptions.NotFound(*exc.args)
    elif isinstance(exc, DjangoPermissionDenied):
        exc = exceptions.PermissionDenied(*exc.args)
    throttled = _anonymous_over_limit(exc, context)
    if throttled is not None:
        exc = throttled
    response = drf_exception_handler(exc, context)
    if response is None:
        return None
    if isinstance(exc, exceptions.ValidationError):
        fields = flatten_field_errors(exc.detail)
        response.data = error_body("invalid", _first_problem(fields), fields)
    elif isinstance(exc, exceptions.APIException):
        response.data = error_body(_error_code(exc), str(exc.detail))
        if isinstance(exc, exceptions.Throttled):
            # DRF leaves the header out when less than a second is left; clients rely on it.
            response["Retry-After"] = str(max(1, int(getattr(exc, "wait", None) or 0)))
    return response


@csrf_exempt  # any method, any path: the answer is the same 404
def api_not_found(request: HttpRequest, path: str = "") -> JsonResponse:
    """Unknown paths under /api/ answer JSON, not the pages' HTML."""
    return JsonResponse(
        error_body(
            "not_found",
            f"There is no API endpoint at {request.path}; the API is described at /api/schema/.",
        ),
        status=404,
    )


# --- Input ----------------------------------------------------------------------------------

# RFC 3339 date-time, as JSON Schema's "date-time" format means it.
RFC3339 = re.compile(
    r"^(?P<date>\d{4}-\d{2}-\d{2})[Tt](?P<hms>\d{2}:\d{2}):(?P<s>\d{2})(?P<frac>\.\d+)?"
    r"(?P<offset>[Zz]|[+-]\d{2}:\d{2})$"
)


class DateTimeInput(serializers.DateTimeField):
    """An instant in RFC 3339, always with its offset (``2026-05-01T10:00:00+01:00``).

    DRF alone also takes dates without a time and other ISO 8601 spellings that the schema's
    ``date-time`` does not allow. A leap second counts as the last microsecond before it.
    """

    def to_internal_value(self, value: Any) -> datetime:
        spelled = rfc3339_iso(value)
        if spelled is None:
            self.fail("invalid", format="RFC 3339, e.g. 2026-05-01T10:00:00+01:00")
        assert spelled is not None
        return super().to_internal_value(spelled)


def rfc3339_iso(value: object) -> str | None:
    """``value`` in the ISO 8601 spelling Django parses, if it is an RFC 3339 instant."""
    match = RFC3339.match(value) if isinstance(value, str) else None
    if match is None:
        return None
    seconds, fraction = match["s"], (match["frac"] or "")[:7]
    if seconds == "60":
        seconds, fraction = "59", ".999999"
    offset = "+00:00" if match["offset"] in "Zz" else match["offset"]
    return f"{match['date']}T{match['hms']}:{seconds}{fraction}{offset}"


def rfc3339_instant(value: object) -> datetime | None:
    """The instant ``DateTimeInput`` reads from ``value``, or None where it would refuse it
    (or the date does not exist): a cheap read for what does not need the field's messages."""
    spelled = rfc3339_iso(value)
    try:
        return parse_datetime(spelled) if spelled is not None else None
    except ValueError:
        return None


class GreaterThan:
    """A validator: the number must be greater than ``limit`` (an exclusive minimum)."""

    def __init__(self, limit: float) -> None:
        self.limit = limit

    def __call__(self, value: float) -> None:
        if not value > self.limit:
            raise serializers.ValidationError(f"Must be greater than {self.limit:g}.")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, GreaterThan) and other.limit == self.limit

    def __hash__(self) -> int:
        return hash(("GreaterThan", self.limit))


_JSON_TYPE_MESSAGES = {
    bool: "Must be true or false.",
    int: "Must be an integer.",
    float: "Must be a number.",
    str: "Must be a string.",
    list: "Must be a list.",
    dict: "Must be an object.",
}


def _json_type(field: serializers.Field) -> type | None:
    """The JSON type a field's value must have in a request body; None: any."""
    if isinstance(field, serializers.BooleanField):
        return bool
    if isinstance(field, serializers.IntegerField | PrimaryKeyRelatedField):
        return int
    if isinstance(field, serializers.FloatField | serializers.DecimalField):
        return float
    if isinstance(field, serializers.MultipleChoiceField):
        return list
    if isinstance(
        field,
        serializers.CharField
        | serializers.ChoiceField
        | serializers.DateTimeField
        | serializers.DateField
        | SlugRelatedField,
    ):
        return str
    if isinstance(field, serializers.ListField | serializers.ListSerializer | ManyRelatedField):
        return list
    if isinstance(field, serializers.Serializer | serializers.DictField):
        return dict
    return None


def _has_json_type(value: Any, expected: type) -> bool:
    if expected is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if expected is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    return isinstance(value, expected)


def _json_type_errors(field: serializers.Field, value: Any) -> Any:
    """Where ``value`` has not the JSON type ``field`` takes (DRF's error shape); None: fine."""
    if value is None:
        return None  # the field says whether it may be null
    expected = _json_type(field)
    if expected is None:
        return None
    if not _has_json_type(value, expected):
        return [_JSON_TYPE_MESSAGES[expected]]
    if expected is str and "\x00" in value:
        return [NUL_MESSAGE]  # DRF lets it through to the database in names it looks up
    child: serializers.Field | None = None
    if isinstance(field, serializers.ListSerializer | serializers.ListField):
        child = field.child
    elif isinstance(field, ManyRelatedField):
        child = field.child_relation
    if child is not None:
        items = {i: _json_type_errors(child, item) for i, item in enumerate(value)}
        items = {i: e for i, e in items.items() if e}
        return items or None
    if isinstance(field, serializers.Serializer):
        errors = {}
        for name, sub in field.fields.items():
            if sub.read_only or name not in value:
                continue
            problem = _json_type_errors(sub, value[name])
            if problem:
                errors[name] = problem
        return errors or None
    return None


_QUERY_SPELLINGS = {
    int: re.compile(r"^[+-]?\d+$"),
    float: re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$"),
    bool: re.compile(r"^(true|false)$"),
}


def _query_spelling_errors(serializer: serializers.Serializer, query: QueryDict) -> dict:
    errors = {}
    for name, field in serializer.fields.items():
        if name not in query:
            continue
        if "\x00" in str(query.get(name)):
            errors[name] = [NUL_MESSAGE]
            continue
        if query.get(name) == "" and not getattr(field, "allow_blank", False):
            # DRF would take an empty value as no value at all.
            errors[name] = ["May not be empty."]
            continue
        expected = _json_type(field)
        pattern = _QUERY_SPELLINGS.get(expected) if expected is not None else None
        if pattern is not None and not pattern.match(str(query.get(name, ""))):
            assert expected is not None
            errors[name] = [_JSON_TYPE_MESSAGES[expected]]
    return errors


def valid_input(
    serializer_class: type[serializers.Serializer],
    data: Any,
    *,
    instance: Any = None,
    partial: bool = False,
) -> dict[str, Any]:
    """A JSON body checked by ``serializer_class``; a 400 with the field errors otherwise."""
    if isinstance(data, QueryDict):
        data = {}  # no body at all
    serializer = serializer_class(instance, data=data, partial=partial)
    if isinstance(data, Mapping):
        problems = _json_type_errors(serializer, data)
        if problems:
            raise exceptions.ValidationError(problems)
    serializer.is_valid(raise_exception=True)
    return dict(serializer.validated_data)


def valid_query(serializer_class: type[serializers.Serializer], query: QueryDict) -> dict[str, Any]:
    """Query parameters checked by ``serializer_class``; a 400 with the field errors otherwise."""
    serializer = serializer_class(data=query)
    problems = _query_spelling_errors(serializer, query)
    if problems:
        raise exceptions.ValidationError(problems)
    serializer.is_valid(raise_exception=True)
    return dict(serializer.validated_data)


def request_user(request: Request) -> User:
    """The authenticated user of an API request (every API view requires one)."""
    user = request.user
    if not isinstance(user, User):
        raise exceptions.NotAuthenticated()
    return user


# --- Answers kept until what they show changes ---------------------------------------------


def cached_json(
    request: Request,
    generations: tuple[Generation, ...],
    parts: tuple[object, ...],
    compute: Callable[[], Any],
) -> HttpResponse | Response:
    """``compute()``'s data as the answer, its JSON rendered once for as long as none of
    ``generations`` moves on (``core.cache``), then served as those bytes: a repeated read
    costs one cache round trip, no query, no serializer and no rendering.

    ``parts`` names what the data depends on besides the generations and the request's URL
    (the user); the full URL and the media type asked for are added here, since the query,
    pagination links and indentation follow them. ``compute`` checks the query itself: an
    invalid one raises and keeps nothing, so a URL found in the cache was valid. A request
    for another renderer than JSON (the browsable API) is answered afresh.
    """
    renderer = getattr(request, "accepted_renderer", None)
    if not isinstance(renderer, JSONRenderer):
        return Response(compute())
    media_type = request.accepted_media_type
    body = cached_answer(
        generations,
        ("json", request.build_absolute_uri(), media_type, *parts),
        lambda: renderer.render(compute(), media_type, {"request": request}),
    )
    return HttpResponse(body, content_type=renderer.media_type)


# --- Throttles ------------------------------------------------------------------------------


def _increment(counter: str, timeout_s: int) -> int:
    """Add one to ``counter`` in the cache, made to expire after ``timeout_s``; its new value.

    On Redis one round trip (INCR and EXPIRE NX in a pipeline): Django's own ``incr`` asks
    whether the key exists first. Elsewhere (the file cache of ``make run``) through the cache
    API, which is not atomic there but needs no server.
    """
    backend = caches["default"]
    if isinstance(backend, RedisCache):
        key = backend.make_and_validate_key(counter)
        client = backend._cache.get_client(key, write=True)  # type: ignore[attr-defined]
        # Not a MULTI/EXEC transaction: INCR alone is atomic, and EXPIRE NX only ever sets
        # the first expiry.
        pipeline = client.pipeline(transaction=False)
        count, _ = pipeline.incr(key).expire(key, timeout_s, nx=True).execute()
        return int(count)
    try:
        return int(cache.incr(counter))
    except ValueError:  # the window's first call
        return 1 if cache.add(counter, 1, timeout_s) else int(cache.incr(counter))


class _WindowCounter:
    """A fixed-window counter: one atomic increment in the cache per request (DRF's own
    throttles read and rewrite a list of timestamps, two round trips and a pickled list).

    A client may make ``num_requests`` calls in each window of ``duration`` seconds; the window
    it is refused in tells it how long to wait. Mixed into a DRF throttle, whose ``get_rate``
    and ``get_cache_key`` say whom it counts and how many.
    """

    rate: str | None
    num_requests: int | None
    duration: int | None
    get_cache_key: Callable[[Request, Any], str | None]
    _wait_s: float = 0.0

    def allow_request(self, request: Request, view: Any) -> bool:
        if self.rate is None or self.num_requests is None or not self.duration:
            return True
        key = self.get_cache_key(request, view)
        if key is None:
            return True
        now = time.time()
        window = int(now // self.duration)
        counter = f"{key}:{window}"
        count = _increment(counter, self.duration + 1)
        self._wait_s = (window + 1) * self.duration - now
        return count <= self.num_requests

    def wait(self) -> float | None:
        return max(1.0, self._wait_s)

    def get_ident(self, request: Request) -> str:
        # The client as the proxies of ours saw it, never DRF's reading of a header the
        # client wrote (core.http.client_address).
        return client_address(request) or ""


class AnonymousThrottle(_WindowCounter, AnonRateThrottle):
    """Requests without valid credentials, per client address (``API_THROTTLE_ANON``).

    The rate is read from the settings on each request, so a test or a deployment can change
    it without reloading DRF's settings; None turns the throttle off.
    """

    def get_rate(self) -> str | None:
        return settings.API_THROTTLE_ANON


class UserThrottle(_WindowCounter, UserRateThrottle):
    """Authenticated requests, per user (``API_THROTTLE_USER``)."""

    def get_rate(self) -> str | None:
        return settings.API_THROTTLE_USER


def _too_many(wait_s: float, detail: str) -> JsonResponse:
    answer = JsonResponse(error_body("throttled", detail), status=429)
    answer["Retry-After"] = str(max(1, math.ceil(wait_s)))
    return answer


def page_throttled(view: Callable[..., HttpResponseBase]) -> Callable[..., HttpResponseBase]:
    """A page route or download counted as the API's requests are: the same throttles and
    rates (``API_THROTTLE_ANON`` per client address, ``API_THROTTLE_USER`` per user), the
    same buckets, so a page is no way around the API's limits. Over the limit, or with too
    many downloads in flight (``Busy``), the answer is 429 with ``Retry-After``."""

    @wraps(view)
    def wrapper(request: HttpRequest, *args: Any, **kwargs: Any) -> HttpResponseBase:
        for throttle in (AnonymousThrottle(), UserThrottle()):
            if not throttle.allow_request(request, None):  # type: ignore[arg-type]
                return _too_many(throttle.wait() or 1.0, "Request was throttled.")
        try:
            return view(request, *args, **kwargs)
        except Busy as exc:
            return _too_many(exc.retry_after_s, exc.message)

    return wrapper


# --- Pagination -----------------------------------------------------------------------------


class Pagination(LimitOffsetPagination):
    """``?limit=&offset=`` on every list that grows; ``{count, next, previous, results}``.

    Unlike DRF's, a limit or offset that is not a whole number in range is refused (400)
    instead of being quietly replaced by the default.
    """

    default_limit = 100
    max_limit = 500

    def _parsed(self, request: Request, name: str, default: int, low: int, high: int | None) -> int:
        raw = request.query_params.get(name)
        if raw is None:
            return default
        if (
            not re.fullmatch(r"\d+", raw)
            or int(raw) < low
            or (high is not None and int(raw) > high)
        ):
            upper = f" and {high}" if high is not None else ""
            raise exceptions.ValidationError(
                {name: [f"Must be a whole number between {low}{upper}."]}
            )
        return int(raw)

    def get_limit(self, request: Request) -> int:
        return self._parsed(request, self.limit_query_param, self.default_limit, 1, self.max_limit)

    def get_offset(self, request: Request) -> int:
        return self._parsed(request, self.offset_query_param, 0, 0, None)

    def get_schema_operation_parameters(self, view: Any) -> list[dict[str, Any]]:
        limit, offset = super().get_schema_operation_parameters(view)
        limit["schema"].update(
            {"minimum": 1, "maximum": self.max_limit, "default": self.default_limit}
        )
        offset["schema"].update({"minimum": 0, "default": 0})
        return [limit, offset]

    def get_paginated_response_schema(self, schema: dict[str, Any]) -> dict[str, Any]:
        paginated = super().get_paginated_response_schema(schema)
        paginated["required"] = ["count", "next", "previous", "results"]
        paginated["properties"]["count"]["minimum"] = 0
        return paginated


def paginated_response(
    *, request: Request, view: Any, queryset: Any, serializer_class: type[serializers.Serializer]
) -> Response:
    """One page of ``queryset`` (ordered by the caller), serialized."""
    data = paginated_data(request=request, queryset=queryset, serializer_class=serializer_class)
    return Response(data)


def paginated_data(
    *,
    request: Request,
    queryset: Any,
    serializer_class: type[serializers.Serializer] | None = None,
    represent: Callable[[list[Any]], list[dict[str, Any]]] | None = None,
) -> dict[str, Any]:
    """One page of ``queryset`` (ordered by the caller) as ``{count, next, previous, results}``,
    each of its rows as ``serializer_class`` shows it, or as ``represent`` shows the page's."""
    paginator = Pagination()
    page = paginator.paginate_queryset(queryset, request)
    assert page is not None  # a limit always applies
    if represent is not None:
        results: Any = represent(page)
    else:
        assert serializer_class is not None, "a serializer or a representation"
        results = serializer_class(page, many=True).data
    return paginator.get_paginated_response(results).data
