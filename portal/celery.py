"""The Celery application of the portal's workers and beat.

Each task runs under a request id (``core/logs.py``): the id of the request or task that
queued it, carried in the message's headers, or a new one; its log lines and its calls to
agents name it. In production (``LOG_FORMAT=json``) Celery's own log handlers write JSON.
"""

from __future__ import annotations

import logging
import os
from typing import Any

from celery import Celery
from celery.signals import (
    after_setup_logger,
    after_setup_task_logger,
    before_task_publish,
    task_postrun,
    task_prerun,
)
from django.conf import settings

from core.logs import (
    RequestIdFilter,
    bind_request_id,
    current_request_id,
    json_handler_formatter,
    unbind_request_id,
)

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "portal.settings")

app = Celery("portal")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.autodiscover_tasks()

REQUEST_ID_TASK_HEADER = "request_id"


@before_task_publish.connect
def _carry_request_id(headers: dict[str, Any] | None = None, **kwargs: Any) -> None:
    request_id = current_request_id()
    if headers is not None and request_id is not None:
        headers.setdefault(REQUEST_ID_TASK_HEADER, request_id)


@task_prerun.connect
def _bind_request_id(task: Any = None, **kwargs: Any) -> None:
    given = getattr(task.request, REQUEST_ID_TASK_HEADER, None) if task is not None else None
    bind_request_id(given if isinstance(given, str) else None)


@task_postrun.connect
def _unbind_request_id(**kwargs: Any) -> None:
    unbind_request_id()


def _own_handlers(logger: logging.Logger, **kwargs: Any) -> None:
    """Celery set up its handlers (worker, beat): give them the request id, and JSON when
    the portal logs JSON."""
    for handler in logger.handlers:
        handler.addFilter(RequestIdFilter())
        if settings.LOG_JSON:
            handler.setFormatter(json_handler_formatter())


after_setup_logger.connect(_own_handlers)
after_setup_task_logger.connect(_own_handlers)
