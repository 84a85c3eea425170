"""Streamed downloads of a run's samples (CSV and JSON), for the API and the pages."""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from typing import Any

from asgiref.sync import sync_to_async
from django.core.handlers.asgi import ASGIRequest
from django.http import StreamingHttpResponse

from portal.runs.models import Run
from portal.runs.selectors import run_samples_csv, run_samples_json


def samples_csv_response(run: Run, *, asynchronous: bool = False) -> StreamingHttpResponse:
    """All samples of a run as CSV, streamed (never built in memory)."""
    return _download(run_samples_csv(run=run), run, "csv", "text/csv", asynchronous)


def samples_json_response(run: Run, *, asynchronous: bool = False) -> StreamingHttpResponse:
    """All samples of a run as one JSON document, streamed."""
    return _download(run_samples_json(run=run), run, "json", "application/json", asynchronous)


def _download(
    chunks: Iterator[str], run: Run, extension: str, media_type: str, asynchronous: bool
) -> StreamingHttpResponse:
    """Under ASGI the chunks come through an async iterator that reads the database in the
    request's sync thread, so the server is never blocked and Django does not buffer it."""
    content: Iterator[str] | AsyncIterator[str] = _async_chunks(chunks) if asynchronous else chunks
    response = StreamingHttpResponse(content, content_type=f"{media_type}; charset=utf-8")
    response["Content-Disposition"] = f'attachment; filename="amazing-run-{run.pk}.{extension}"'
    return response


def _next_or_none(chunks: Iterator[str]) -> str | None:
    return next(chunks, None)


async def _async_chunks(chunks: Iterator[str]) -> AsyncIterator[str]:
    next_chunk = sync_to_async(_next_or_none, thread_sensitive=True)
    while True:
        chunk = await next_chunk(chunks)
        if chunk is None:
            return
        yield chunk


def is_asgi(request: Any) -> bool:
    return isinstance(getattr(request, "_request", request), ASGIRequest)
