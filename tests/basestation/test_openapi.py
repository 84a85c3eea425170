"""docs/agent-openapi.yaml describes exactly the routes the agent serves, and the agent's
real answers match the schemas it gives."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from flask import Flask
from flask.testing import FlaskClient
from jsonschema import Draft202012Validator
from referencing import Registry, Resource
from referencing.jsonschema import DRAFT202012
from werkzeug.test import TestResponse

from tests.basestation.conftest import run_body

SPEC_PATH = Path(__file__).resolve().parents[2] / "docs" / "agent-openapi.yaml"
SPEC_URI = "urn:amazing:agent-openapi"
HTTP_METHODS = {"get", "put", "post", "delete", "patch", "head", "options", "trace"}

Drive = Callable[[float, float], float]


@pytest.fixture(scope="module")
def spec() -> dict[str, Any]:
    loaded = yaml.safe_load(SPEC_PATH.read_text(encoding="utf-8"))
    assert isinstance(loaded, dict)
    return loaded


def _flask_routes(app: Flask) -> set[tuple[str, str]]:
    routes = set()
    for rule in app.url_map.iter_rules():
        if rule.endpoint == "static":
            continue
        path = re.sub(r"<(?:[^:<>]+:)?([^<>]+)>", r"{\1}", rule.rule)
        for method in rule.methods or ():
            if method not in ("HEAD", "OPTIONS"):
                routes.add((method, path))
    return routes


def _spec_routes(spec: dict[str, Any]) -> set[tuple[str, str]]:
    return {
        (method.upper(), path)
        for path, item in spec["paths"].items()
        for method in item
        if method in HTTP_METHODS
    }


def test_it_is_an_openapi_3_1_document(spec: dict[str, Any]) -> None:
    assert spec["openapi"].startswith("3.1.")
    assert spec["info"]["title"]
    assert spec["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"
    for name, schema in spec["components"]["schemas"].items():
        try:
            Draft202012Validator.check_schema(schema)
        except Exception as exc:  # pragma: no cover - the message names the schema
            pytest.fail(f"components.schemas.{name}: {exc}")


def test_every_route_of_the_app_is_described_and_nothing_else(
    app: Flask, spec: dict[str, Any]
) -> None:
    served, described = _flask_routes(app), _spec_routes(spec)
    assert served - described == set(), "served but not in docs/agent-openapi.yaml"
    assert described - served == set(), "in docs/agent-openapi.yaml but not served"


def test_every_operation_documents_its_answers_and_the_token(spec: dict[str, Any]) -> None:
    for path, item in spec["paths"].items():
        for method, operation in item.items():
            if method not in HTTP_METHODS:
                continue
            assert operation.get("operationId"), (method, path)
            statuses = set(operation["responses"])
            assert "200" in statuses, (method, path)
            if path.startswith("/api/v1/"):
                assert "401" in statuses, (method, path)
                assert operation.get("security") != [], (method, path)


# -- the answers match the schemas ----------------------------------------------------------------


class Checker:
    def __init__(self, spec: dict[str, Any]) -> None:
        self.spec = spec
        resource = Resource.from_contents(spec, default_specification=DRAFT202012)
        self.registry: Registry[Any] = Registry().with_resource(SPEC_URI, resource)
        self.checked: set[tuple[str, str, str]] = set()

    def _resolve(self, node: dict[str, Any]) -> dict[str, Any]:
        while "$ref" in node:
            target: Any = self.spec
            for part in node["$ref"].removeprefix("#/").split("/"):
                target = target[part]
            node = target
        return node

    def __call__(self, method: str, path: str, response: TestResponse) -> dict[str, Any]:
        status = str(response.status_code)
        operation = self.spec["paths"][path][method.lower()]
        assert status in operation["responses"], f"{method} {path} answered undocumented {status}"
        documented = self._resolve(operation["responses"][status])
        if "text/plain" in documented["content"]:  # the metrics: text, not JSON
            assert response.mimetype == "text/plain", f"{method} {path}: {response.mimetype}"
            self.checked.add((method, path, status))
            return {"text": response.get_data(as_text=True)}
        schema = documented["content"]["application/json"]["schema"]
        body = response.get_json()
        errors = self.errors(schema, body)
        assert not errors, f"{method} {path} {status}: " + "; ".join(errors)
        self.checked.add((method, path, status))
        assert isinstance(body, dict)
        return body

    def errors(self, schema: dict[str, Any], instance: Any) -> list[str]:
        validator = Draft202012Validator(_rebase(schema, SPEC_URI), registry=self.registry)
        return [
            f"{list(error.absolute_path)}: {error.message}"
            for error in sorted(validator.iter_errors(instance), key=lambda e: list(e.path))
        ]


def _rebase(schema: Any, base: str) -> Any:
    """Point the schema's local ``#/components/...`` references at the whole document."""
    if isinstance(schema, dict):
        return {
            key: (f"{base}{value}" if key == "$ref" else _rebase(value, base))
            for key, value in schema.items()
        }
    if isinstance(schema, list):
        return [_rebase(item, base) for item in schema]
    return schema


def test_the_checker_catches_an_answer_that_breaks_its_schema(
    client: FlaskClient, auth: dict[str, str], spec: dict[str, Any]
) -> None:
    check = Checker(spec)
    status = client.get("/api/v1/status", headers=auth).get_json()
    schema = {"$ref": "#/components/schemas/Status"}
    assert check.errors(schema, status) == []
    del status["battery"]
    status["link"]["state"] = "sideways"
    assert len(check.errors(schema, status)) == 2


def test_the_agents_answers_match_the_described_schemas(
    client: FlaskClient, auth: dict[str, str], spec: dict[str, Any], drive: Drive
) -> None:
    check = Checker(spec)
    run = "/api/v1/runs/{run_id}"
    samples = "/api/v1/runs/{run_id}/samples"

    check("GET", "/healthz", client.get("/healthz"))
    check("GET", "/api/v1/status", client.get("/api/v1/status", headers=auth))
    check("GET", "/api/v1/battery", client.get("/api/v1/battery", headers=auth))
    check("GET", "/api/v1/rail", client.get("/api/v1/rail", headers=auth))
    check("GET", "/api/v1/metrics", client.get("/api/v1/metrics", headers=auth))
    check("GET", "/api/v1/status", client.get("/api/v1/status"))  # 401

    start_s = time.time() + 0.5
    check("PUT", run, client.put("/api/v1/runs/r1", json=run_body(start_s), headers=auth))
    check("PUT", run, client.put("/api/v1/runs/r1", json=run_body(start_s), headers=auth))
    changed = run_body(start_s, title="other")
    check("PUT", run, client.put("/api/v1/runs/r1", json=changed, headers=auth))  # 409
    check("PUT", run, client.put("/api/v1/runs/r1", json={"owner": 1}, headers=auth))  # 422
    check("PUT", run, client.put("/api/v1/runs/r1", data="x", headers=auth))  # 415
    big = b"{" + b" " * 70_000 + b"}"
    response = client.put(
        "/api/v1/runs/r1", data=big, content_type="application/json", headers=auth
    )
    check("PUT", run, response)  # 413

    drive(start_s, start_s + 1.0)
    check("GET", "/api/v1/status", client.get("/api/v1/status", headers=auth))
    check("GET", "/api/v1/battery", client.get("/api/v1/battery", headers=auth))
    check("GET", "/api/v1/runs", client.get("/api/v1/runs", headers=auth))
    check("GET", "/api/v1/runs", client.get("/api/v1/runs?state=nope", headers=auth))
    check("GET", run, client.get("/api/v1/runs/r1", headers=auth))
    check("GET", run, client.get("/api/v1/runs/nope", headers=auth))
    check("GET", samples, client.get("/api/v1/runs/r1/samples?limit=5", headers=auth))
    check("GET", samples, client.get("/api/v1/runs/r1/samples?limit=0", headers=auth))
    check("GET", samples, client.get("/api/v1/runs/nope/samples", headers=auth))

    control = {"user": "admin", "velocity_mps": 0.3, "direction": "cw"}
    check("POST", "/api/v1/control", client.post("/api/v1/control", json=control, headers=auth))
    forced = {**control, "force": True}
    check("POST", "/api/v1/control", client.post("/api/v1/control", json=forced, headers=auth))
    check("GET", "/api/v1/status", client.get("/api/v1/status", headers=auth))
    check("DELETE", run, client.delete("/api/v1/runs/r1", headers=auth))  # 409 already ended
    check("DELETE", run, client.delete("/api/v1/runs/nope", headers=auth))
    stopped = control | {"velocity_mps": 0}
    check("POST", "/api/v1/control", client.post("/api/v1/control", json=stopped, headers=auth))
    check("POST", "/api/v1/control", client.post("/api/v1/control", json={}, headers=auth))

    check("POST", "/api/v1/stop", client.post("/api/v1/stop", headers=auth))
    check("GET", "/api/v1/status", client.get("/api/v1/status", headers=auth))
    check("POST", "/api/v1/control", client.post("/api/v1/control", json=control, headers=auth))
    check("POST", "/api/v1/stop", client.post("/api/v1/stop", json={"x": 1}, headers=auth))
    check("POST", "/api/v1/stop", client.post("/api/v1/stop", data="x", headers=auth))
    release = "/api/v1/stop/release"
    check("POST", release, client.post(release, headers=auth))
    check("POST", release, client.post(release, json={"reason": "x"}, headers=auth))

    day = time.strftime("%Y-%m-%d", time.gmtime(start_s))
    check("GET", "/api/v1/logs/{day}", client.get(f"/api/v1/logs/{day}", headers=auth))
    check("GET", "/api/v1/logs/{day}", client.get("/api/v1/logs/2019-02-30", headers=auth))

    later_s = time.time() + 3600
    check("PUT", run, client.put("/api/v1/runs/r2", json=run_body(later_s), headers=auth))
    check("DELETE", run, client.delete("/api/v1/runs/r2", headers=auth))

    # Every operation was exercised with its success answer.
    for method, path in _spec_routes(spec):
        assert (method, path, "200") in check.checked or (method, path, "201") in check.checked
