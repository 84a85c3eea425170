from __future__ import annotations

from datetime import datetime
from typing import Any
from zoneinfo import ZoneInfo

from django import forms
from django.conf import settings
from django.core.exceptions import ValidationError
from django.db.models import Case, When
from django.forms.fields import BaseTemporalField
from django.utils import timezone
from django.utils.dateparse import parse_datetime

from bookings.choices import ResourceKind
from bookings.models import Resource
from bookings.selectors import resources_bookable
from core.accounts.models import User
from core.accounts.services import TOKEN_EXPIRY_MAX_DAYS, TOKEN_NAME_MAX_LENGTH
from core.errors import DomainError
from core.events.catalogue import EVENT_TYPES
from core.wall_clock import NonexistentLocalTime, local_instant
from core.webhooks.services import STAFF_ONLY_PREFIXES
from portal.experiments.models import Experiment
from portal.experiments.selectors import experiments_visible


def form_refusal(form: forms.Form, exc: DomainError) -> None:
    """Show a service's refusal on the form, next to the field it names when the form has it."""
    for field, errors in (exc.fields or {"__all__": [exc.message]}).items():
        for message in errors:
            form.add_error(field if field in form.fields else None, message)


class PassForm(forms.Form):
    """Where along the rail the run page lists the robot's passes."""

    at_m = forms.FloatField(
        label="Position along the rail (m)",
        min_value=0,
        required=False,
        widget=forms.NumberInput(attrs={"step": "0.1", "inputmode": "decimal"}),
    )


class ExperimentForm(forms.Form):
    """Title plus the segment rows, which arrive as parallel lists (one entry per table row)."""

    title = forms.CharField(max_length=200)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.segment_rows: list[dict[str, str]] = []

    def segments_from(self, data: Any) -> list[dict[str, Any]]:
        velocities = data.getlist("velocity_mps")
        directions = data.getlist("direction")
        durations = data.getlist("duration_s")
        segments: list[dict[str, Any]] = []
        for velocity, direction, duration in zip(velocities, directions, durations, strict=False):
            self.segment_rows.append(
                {"velocity_mps": velocity, "direction": direction, "duration_s": duration}
            )
            if not velocity.strip() and not duration.strip():
                continue  # An empty row the page offered but the user did not fill.
            segments.append(
                {
                    "velocity_mps": velocity.strip(),
                    "direction": direction,
                    "duration_s": duration.strip(),
                }
            )
        return segments


class LocalDateTimeField(forms.DateTimeField):
    """A ``datetime-local`` input, read in the testbed's time zone by ``local_instant``.

    A value with a UTC offset is that instant. A wall-clock time the clocks pass twice is its
    first occurrence (summer time); one they skip is an error that says so.
    """

    widget = forms.DateTimeInput(
        attrs={"type": "datetime-local", "step": "1"}, format="%Y-%m-%dT%H:%M:%S"
    )
    input_formats = ["%Y-%m-%dT%H:%M:%S", "%Y-%m-%dT%H:%M"]

    def to_python(self, value: Any) -> datetime | None:
        if value in self.empty_values:
            return None
        result: datetime | None = value if isinstance(value, datetime) else None
        if result is None:
            try:
                result = parse_datetime(str(value).strip())
            except ValueError:
                raise ValidationError(self.error_messages["invalid"], code="invalid") from None
        if result is None:
            # Not ISO 8601: the input formats. (Not DateTimeField's own to_python: it converts
            # too, and refuses both the repeated and the skipped hour without saying which.)
            result = BaseTemporalField.to_python(self, value)
            assert result is not None
        if timezone.is_aware(result):
            return result
        try:
            return local_instant(result, ZoneInfo(settings.TIME_ZONE))
        except NonexistentLocalTime as exc:
            raise ValidationError(str(exc), code="nonexistent") from None


class ExperimentChoiceField(forms.ModelChoiceField):
    """An experiment by its title and its program's length, as the booking dialog names it."""

    def label_from_instance(self, obj: Any) -> str:
        return f"{obj.title} ({obj.duration_s:g} s)"


class ResourcesField(forms.ModelMultipleChoiceField):
    """Resources by name, a robot said to be one."""

    def label_from_instance(self, obj: Any) -> str:
        return f"{obj.name} (robot)" if obj.is_mobile else obj.name


class BookingForm(forms.Form):
    """One booking of a robot and fixed nodes together (the timeline's: one lease for the
    nodes, the robot's run), robots listed first."""

    resources = ResourcesField(
        queryset=Resource.objects.none(),
        to_field_name="name",
        widget=forms.CheckboxSelectMultiple,
        label="Resources",
    )
    experiment = ExperimentChoiceField(
        queryset=Experiment.objects.none(),
        required=False,
        help_text="What the robot runs: needed when a robot is booked.",
    )
    start_at = LocalDateTimeField(label="Start")
    end_at = LocalDateTimeField(label="End")

    def __init__(self, *args: Any, user: User, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        robots_first = Case(When(kind=ResourceKind.MOBILE, then=0), default=1)
        self.fields["resources"].queryset = resources_bookable().order_by(robots_first, "name")  # type: ignore[attr-defined]
        self.fields["experiment"].queryset = experiments_visible(user=user).filter(owner=user)  # type: ignore[attr-defined]


class QueueRequestForm(forms.Form):
    """A run as soon as possible (``portal.queue``): the service checks the rest."""

    experiment = ExperimentChoiceField(queryset=Experiment.objects.none())
    robot = forms.ModelChoiceField(queryset=Resource.objects.none(), to_field_name="name")
    earliest_at = LocalDateTimeField(label="No sooner than", required=False)
    latest_end_at = LocalDateTimeField(label="Ended by")
    duration_s = forms.IntegerField(
        label="Duration (s)",
        min_value=1,
        required=False,
        help_text="Default: the program, to a whole minute.",
    )
    hours_from = forms.IntegerField(
        label="Allowed from (hour)", min_value=0, max_value=23, required=False
    )
    hours_to = forms.IntegerField(
        label="Allowed until (hour)",
        min_value=1,
        max_value=24,
        required=False,
        help_text="The testbed's hours; 22 to 6 is nights only. Empty: any hour.",
    )

    def __init__(self, *args: Any, user: User, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.fields["experiment"].queryset = experiments_visible(user=user).filter(owner=user)  # type: ignore[attr-defined]
        self.fields["robot"].queryset = resources_bookable().filter(kind=ResourceKind.MOBILE)  # type: ignore[attr-defined]


class ApiTokenForm(forms.Form):
    name = forms.CharField(
        max_length=TOKEN_NAME_MAX_LENGTH, help_text="Where it is used, e.g. laptop."
    )
    expires_in_days = forms.IntegerField(
        label="Expires in (days)",
        min_value=1,
        max_value=TOKEN_EXPIRY_MAX_DAYS,
        required=False,
        help_text="Empty: until you revoke it.",
    )


class WebhookForm(forms.Form):
    """A new webhook: where to send, and which of the user's events (staff: also the robots'
    and the scheduler link's)."""

    url = forms.URLField(
        label="URL",
        max_length=500,
        assume_scheme="https",
        help_text="https, at a public address: the portal checks it before each try.",
    )
    description = forms.CharField(max_length=200, required=False, help_text="What it is for.")
    types = forms.MultipleChoiceField(
        label="Only these events",
        required=False,
        widget=forms.CheckboxSelectMultiple,
        help_text="None ticked: all of yours.",
    )
    staff_events = forms.BooleanField(
        label="Also the robots' and the scheduler link's events",
        required=False,
    )

    def __init__(self, *args: Any, staff: bool, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        types = self.fields["types"]
        assert isinstance(types, forms.MultipleChoiceField)
        types.choices = [
            (name, f"{name}: {kind.description}")
            for name, kind in sorted(EVENT_TYPES.items())
            if staff or not name.startswith(STAFF_ONLY_PREFIXES)
        ]
        if not staff:
            del self.fields["staff_events"]


class MeasurementForm(forms.Form):
    """A measurement file added to a run as a series (the run page's "Add measurements")."""

    file = forms.FileField(
        label="File (CSV, JSON or Parquet)",
        help_text="A time column (RFC 3339 with its UTC offset, or Unix seconds) and numbers.",
        widget=forms.ClearableFileInput(attrs={"accept": ".csv,.json,.parquet,.pq"}),
    )
    name = forms.SlugField(
        max_length=64, label="Series name", help_text="For example rssi or throughput."
    )
    unit = forms.CharField(max_length=32, required=False, label="Unit")
    time_column = forms.CharField(
        max_length=64, required=False, label="Time column", help_text="Default: t, time, …"
    )
    clock_offset_s = forms.FloatField(
        required=False,
        label="Clock offset (s)",
        help_text="Added to the file's times: how far your clock was behind the base station's.",
        widget=forms.NumberInput(attrs={"step": "any", "inputmode": "decimal"}),
    )
    source_node = forms.CharField(max_length=64, required=False, label="Measured by (node)")
    description = forms.CharField(
        max_length=2000, required=False, widget=forms.Textarea(attrs={"rows": 2})
    )


class MeasurementOffsetForm(forms.Form):
    """A series's clock offset, set again."""

    clock_offset_s = forms.FloatField(
        label="Clock offset (s)", widget=forms.NumberInput(attrs={"step": "any"})
    )
