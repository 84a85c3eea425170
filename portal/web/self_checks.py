"""A robot's self-checks page (admins): each check's figures against its limits and baseline,
their trend, a button to book the next check and one to make a check the baseline. The same
services as the REST API's (``portal.runs.services.self_check``)."""

from __future__ import annotations

from datetime import time
from typing import Any

from django.contrib import messages
from django.http import HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.utils import timezone

from bookings.choices import Channel
from bookings.models import Resource
from core.accounts.models import User
from core.accounts.staff import staff_required
from core.audit.services import client_ip
from core.errors import DomainError, InvalidInput
from portal.runs.models import SelfCheck
from portal.runs.selectors import (
    self_check_baseline_of,
    self_check_schedule_of,
    self_checks_of,
)
from portal.runs.self_check import RULES
from portal.runs.services.self_check import (
    self_check_baseline_set,
    self_check_book,
    self_check_schedule_set,
)


@staff_required
def robot_self_checks(request: HttpRequest, name: str) -> HttpResponse:
    robot = get_object_or_404(Resource, name=name, kind="mobile")
    if request.method == "POST":
        return _act(request, robot)
    checks = self_checks_of(robot)
    baseline = self_check_baseline_of(robot)
    schedule = self_check_schedule_of(robot)
    return render(
        request,
        "web/self_checks.html",
        {
            "resource": robot,
            "checks": checks,
            "rules": RULES,
            "baseline": baseline,
            "schedule": schedule,
            "rows": [_row(check, baseline.source_id if baseline else None) for check in checks],
            # Oldest first for the trend chart: time along x.
            "trend": {
                "at": [c.run.start_at.isoformat() for c in reversed(checks) if c.figures],
                "figures": {
                    key: [c.figures.get(key) for c in reversed(checks) if c.figures]
                    for key in RULES
                },
                "labels": {key: _label(key) for key in RULES},
                "baseline": baseline.figures if baseline is not None else None,
            },
        },
    )


def _label(key: str) -> str:
    rule = RULES[key]
    return f"{rule.label} ({rule.unit})" if rule.unit else f"{rule.label} (share)"


def _row(check: SelfCheck, baseline_id: int | None) -> dict[str, Any]:
    # A problem's text starts with its figure's label (``self_check_judge``).
    flagged = {
        key for key, rule in RULES.items() if any(p.startswith(rule.label) for p in check.problems)
    }
    return {
        "check": check,
        "cells": [(key, check.figures.get(key), key in flagged) for key in RULES],
        "is_baseline": check.pk == baseline_id,
        "can_be_baseline": bool(check.figures)
        and all(v is not None for v in check.figures.values())
        and check.pk != baseline_id,
    }


def _act(request: HttpRequest, robot: Resource) -> HttpResponse:
    user = request.user
    assert isinstance(user, User)  # staff_required let only a signed-in admin through
    try:
        action = request.POST.get("action")
        if action == "schedule":
            _schedule(request, robot, user)
        elif action == "baseline":
            check = get_object_or_404(SelfCheck, pk=request.POST.get("check"), resource=robot)
            self_check_baseline_set(check=check, by=user, ip=client_ip(request))
            messages.success(request, f"Check {check.pk} is now the baseline.")
        else:
            check = self_check_book(resource=robot, by=user, via=Channel.WEB, ip=client_ip(request))
            start = timezone.localtime(check.run.start_at)
            messages.success(
                request, f"Self-check booked for {start:%Y-%m-%d %H:%M:%S} (run {check.run_id})."
            )
    except DomainError as exc:
        messages.error(request, exc.message)
    return redirect("robot-self-checks", name=robot.name)


def _schedule(request: HttpRequest, robot: Resource, user: User) -> None:
    """Set the daily time (``at``, HH:MM) or stop (``stop``)."""
    at: time | None = None
    if "stop" not in request.POST:
        try:
            at = time.fromisoformat(request.POST.get("at", ""))
        except ValueError as exc:
            raise InvalidInput.on_field("at", "Give the time as HH:MM.") from exc
    self_check_schedule_set(resource=robot, by=user, at=at, ip=client_ip(request))
    messages.success(
        request,
        f"A self-check will be booked every day at {at:%H:%M}."
        if at
        else "Daily self-checks stopped.",
    )
