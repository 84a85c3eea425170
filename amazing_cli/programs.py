"""Experiment files: YAML or JSON, checked against the portal's own schema before sending.

A file holds what ``POST /api/v1/experiments/`` takes::

    title: two laps, there and back
    segments:
      - {velocity_mps: 0.5, direction: cw, duration_s: 60}
      - {velocity_mps: 0.8, direction: ccw, duration_s: 60}

The request schema comes from the portal (``/api/schema/``), so the file is held to exactly
what the portal states; what only the portal knows (each robot's velocity limit) it checks
when the experiment is created.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from amazing_cli.errors import bad_input

REQUEST_COMPONENT = "ExperimentRequest"


def load(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise bad_input(f"{path}: no such file") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise bad_input(f"{path}: cannot read it: {exc}") from exc
    if path.suffix.lower() == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise bad_input(f"{path}: not valid JSON: {exc}") from exc
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        at = f" at line {where.line + 1}, column {where.column + 1}" if where else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise bad_input(f"{path}: not valid YAML{at}: {problem}") from exc


def _location(error: jsonschema.ValidationError) -> str:
    return ".".join(str(p) for p in error.absolute_path) or "(the file)"


def validate(document: Any, *, schema: dict[str, Any], source: Path) -> dict[str, Any]:
    """``document`` if the portal's request schema allows it; else the first problem."""
    components = schema.get("components", {})
    if REQUEST_COMPONENT not in components.get("schemas", {}):
        raise bad_input(f"the portal's schema has no {REQUEST_COMPONENT}; is the CLI too new?")
    # OpenAPI 3.0 schemas are JSON Schema draft 4 with a few keywords more; the references
    # resolve within the portal's document.
    root = {"$ref": f"#/components/schemas/{REQUEST_COMPONENT}", "components": components}
    validator = jsonschema.Draft4Validator(root)
    errors = sorted(validator.iter_errors(document), key=lambda e: list(e.absolute_path))
    if errors:
        first = errors[0]
        raise bad_input(f"{source}: {_location(first)}: {first.message}")
    assert isinstance(document, dict)
    return document
