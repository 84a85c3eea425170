"""Streamed downloads of a run's samples (CSV and JSON), for the API and the pages.

Gzipped when the client accepts it: telemetry text shrinks several times, so a download
over a slow link finishes sooner than the database takes to produce it.

A download holds a database cursor and a server thread until its last byte: a user (or an
anonymous client address) has at most ``DOWNLOADS_IN_FLIGHT_MAX`` in flight, the next one
is refused with 429 and ``Retry-After`` (``core.errors.Busy``).
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import AsyncIterator, Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any

from asgiref.sync import sync_to_async
from django.conf import settings
from django.core.cache import cache
from django.core.handlers.asgi import ASGIRequest
from django.http import HttpRequest, StreamingHttpResponse
from django.urls import reverse
from django.utils.cache import patch_vary_headers
from rest_framework.request import Request

from core.errors import Busy
from core.http import client_address
from portal.runs.measurement_tables import parquet_bytes, samples_table, series_table
from portal.runs.models import MeasurementSeries, Run
from portal.runs.package import run_package_zip, runs_package_zip
from portal.runs.selectors import run_samples_csv, run_samples_json

# A refused download is told to try again after this long.
DOWNLOAD_RETRY_AFTER_S = 5

PARQUET_TYPE = "application/vnd.apache.parquet"
BINARY_TYPES = ("application/zip", PARQUET_TYPE)

# zlib's fastest level: it keeps up with the database (level 6 takes several times as long
# for a few per cent less).
GZIP_LEVEL = 1


def samples_csv_response(request: HttpRequest | Request, run: Run) -> StreamingHttpResponse:
    """All samples of a run as CSV, streamed (never built in memory)."""
    return _download(request, run_samples_csv(run=run), run, "csv", "text/csv")


def samples_json_response(request: HttpRequest | Request, run: Run) -> StreamingHttpResponse:
    """All samples of a run as one JSON document, streamed."""
    return _download(request, run_samples_json(run=run), run, "json", "application/json")


def run_package_response(request: HttpRequest | Request, run: Run) -> StreamingHttpResponse:
    """The run as a self-describing zip (``portal/runs/package.py``), streamed. Not gzipped
    again: its files are deflated inside it."""
    url = request.build_absolute_uri(reverse("run", args=[run.pk]))
    return _download(
        request, run_package_zip(run=run, url=url), run, "zip", "application/zip", gzip=False
    )


def _parquet_chunks(build: Callable[[], bytes]) -> Iterator[bytes]:
    # Built when the first chunk is asked for: inside the download slot, in the server's
    # thread for it. Parquet's footer comes last, so the file is made whole first.
    yield build()


def samples_parquet_response(request: HttpRequest | Request, run: Run) -> StreamingHttpResponse:
    """The run's samples as one Parquet file (typed columns, times in UTC)."""
    chunks = _parquet_chunks(
        lambda: parquet_bytes(samples_table(run), metadata={"amazing_run": str(run.pk)})
    )
    return _download(request, chunks, run, "parquet", PARQUET_TYPE, gzip=False)


def series_parquet_response(
    request: HttpRequest | Request, series: MeasurementSeries
) -> StreamingHttpResponse:
    """A measurement series placed on the path (``measurement_tables.series_table``) as one
    Parquet file."""
    metadata = {"amazing_run": str(series.run_id), "amazing_series": series.name}
    chunks = _parquet_chunks(lambda: parquet_bytes(series_table(series), metadata=metadata))
    name = f"amazing-run-{series.run_id}-{series.name}"
    return _download(request, chunks, series.run, "parquet", PARQUET_TYPE, gzip=False, name=name)


def runs_package_response(
    request: HttpRequest | Request,
    runs: Sequence[Run],
    *,
    name: str | None = None,
    extra: Mapping[str, dict[str, Any]] | None = None,
) -> StreamingHttpResponse:
    """Several runs as one zip: each run's package in a folder, a manifest and ``extra``'s
    documents (``portal/runs/package.py`` ``runs_package_zip``), streamed; ``name`` the
    file's, without its extension."""
    urls = {run.pk: request.build_absolute_uri(reverse("run", args=[run.pk])) for run in runs}
    if name is None:
        name = "amazing-runs-" + "-".join(str(run.pk) for run in runs[:5])
        if len(runs) > 5:
            name += f"-and-{len(runs) - 5}-more"
    return _download(
        request,
        runs_package_zip(runs=runs, urls=urls, extra=extra),
        runs[0] if runs else None,
        "zip",
        "application/zip",
        gzip=False,
        name=name,
    )


def accepts_gzip(accept_encoding: str) -> bool:
    """Whether an ``Accept-Encoding`` header admits gzip (``gzip`` or ``*``, not at q=0)."""
    for item in accept_encoding.split(","):
        coding, _, params = item.strip().partition(";")
        if coding.strip().lower() not in ("gzip", "x-gzip", "*"):
            continue
        quality = 1.0
        for param in params.split(";"):
            name, _, value = param.strip().partition("=")
            if name.strip().lower() == "q":
                try:
                    quality = float(value)
                except ValueError:
                    quality = 0.0
        if quality > 0:
            return True
    return False


def gzipped(chunks: Iterable[bytes], level: int = GZIP_LEVEL) -> Iterator[bytes]:
    """The chunks as one gzip stream, compressed as they come (never held whole)."""
    compressor = zlib.compressobj(level, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
    for chunk in chunks:
        compressed = compressor.compress(chunk)
        if compressed:
            yield compressed
    yield compressor.flush()


def _download(
    request: HttpRequest | Request,
    chunks: Iterator[bytes],
    run: Run | None,
    extension: str,
    media_type: str,
    *,
    gzip: bool = True,
    name: str | None = None,
) -> StreamingHttpResponse:
    """Under ASGI the chunks come through an async iterator that reads the database (and
    compresses) in the request's sync thread, so the server is never blocked and Django
    does not buffer it."""
    release = _download_slot(request)
    compress = gzip and accepts_gzip(request.META.get("HTTP_ACCEPT_ENCODING", ""))
    if compress:
        chunks = gzipped(chunks)
    chunks = _Held(chunks, release)
    content: Iterator[bytes] | AsyncIterator[bytes] = (
        _async_chunks(chunks) if _is_asgi(request) else chunks
    )
    charset = "" if media_type in BINARY_TYPES else "; charset=utf-8"
    response = StreamingHttpResponse(content, content_type=f"{media_type}{charset}")
    if name is None:
        assert run is not None, "a download of no run is named by its caller"
        name = f"amazing-run-{run.pk}"
    filename = f"{name}.{extension}"
    response["Content-Disposition"] = f'attachment; filename="{filename}"'
    if compress:
        response["Content-Encoding"] = "gzip"
    patch_vary_headers(response, ("Accept-Encoding",))
    return response


def _download_slot(request: HttpRequest | Request) -> Callable[[], object]:
    """One of the client's ``DOWNLOADS_IN_FLIGHT_MAX`` slots, taken atomically (``add`` is
    SET NX on Redis); the function that gives it back. A slot a killed process never gave
    back frees itself after ``DOWNLOAD_SLOT_S``."""
    user = getattr(request, "user", None)
    who = f"user-{user.pk}" if user is not None and user.is_authenticated else None
    who = who or f"address-{client_address(request)}"
    for index in range(settings.DOWNLOADS_IN_FLIGHT_MAX):
        key = f"downloads-in-flight:{who}:{index}"
        if cache.add(key, 1, settings.DOWNLOAD_SLOT_S):
            return functools.partial(cache.delete, key)
    raise Busy(
        f"At most {settings.DOWNLOADS_IN_FLIGHT_MAX} downloads at a time: "
        "let one finish, then try again.",
        retry_after_s=DOWNLOAD_RETRY_AFTER_S,
    )


class _Held:
    """The chunks of a download holding a slot, given back when the response is closed
    (the server closes it after the last byte, or when the client goes away) or the chunks
    run out, whichever comes first; once."""

    def __init__(self, chunks: Iterator[bytes], release: Callable[[], object]) -> None:
        self._chunks = chunks
        self._release: Callable[[], object] | None = release

    def __iter__(self) -> Iterator[bytes]:
        return self

    def __next__(self) -> bytes:
        try:
            return next(self._chunks)
        except StopIteration:
            self.close()
            raise

    def close(self) -> None:
        release, self._release = self._release, None
        if release is None:
            return
        try:
            close = getattr(self._chunks, "close", None)
            if close is not None:
                close()
        finally:
            release()


def _next_or_none(chunks: Iterator[bytes]) -> bytes | None:
    return next(chunks, None)


async def _async_chunks(chunks: Iterator[bytes]) -> AsyncIterator[bytes]:
    next_chunk = sync_to_async(_next_or_none, thread_sensitive=True)
    try:
        while True:
            chunk = await next_chunk(chunks)
            if chunk is None:
                return
            yield chunk
    finally:
        close = getattr(chunks, "close", None)
        if close is not None:
            await sync_to_async(close, thread_sensitive=True)()


def _is_asgi(request: Any) -> bool:
    return isinstance(getattr(request, "_request", request), ASGIRequest)
