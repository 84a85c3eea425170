"""SCHEDULER_* variables: parsed and checked at start, every bad value a clear error."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bookings.scheduler import build_scheduler
from bookings.scheduler.config import ENV_NAMES, SchedulerConfig, from_env
from bookings.scheduler.omf import OmfScheduler

REPO = Path(__file__).resolve().parents[3]


def test_no_url_means_no_scheduler() -> None:
    assert from_env({}) is None
    assert from_env({"SCHEDULER_URL": "  "}) is None


def test_a_setting_without_the_url_is_an_error_not_ignored() -> None:
    with pytest.raises(ValueError, match="SCHEDULER_TOKEN set but SCHEDULER_URL is not"):
        from_env({"SCHEDULER_TOKEN": "t0ken"})


def test_the_defaults_reach_every_fixed_node_of_an_omf_broker() -> None:
    config = from_env({"SCHEDULER_URL": "https://broker.example.org:8001/"})
    assert config == SchedulerConfig(base_url="https://broker.example.org:8001")
    assert config.dialect == "omf"
    assert config.account_name == "amazing"
    assert config.timeouts_s == (3.0, 10.0)
    assert config.verify_tls
    assert config.owns(resource_name="node-07", is_fixed_node=True)
    assert not config.owns(resource_name="mobile-1", is_fixed_node=False)
    assert isinstance(build_scheduler(config), OmfScheduler)


def test_every_setting_is_read(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text("s3cret-token\n")
    cert, key, bundle = (tmp_path / name for name in ("cert.pem", "key.pem", "ca.pem"))
    for path in (cert, key, bundle):
        path.write_text("-----BEGIN-----\n")
    config = from_env(
        {
            "SCHEDULER_URL": "https://broker:8001/am",
            "SCHEDULER_DIALECT": "omf",
            "SCHEDULER_ACCOUNT": "amazing.portal",
            "SCHEDULER_TOKEN_FILE": str(token_file),
            "SCHEDULER_CLIENT_CERT": str(cert),
            "SCHEDULER_CLIENT_KEY": str(key),
            "SCHEDULER_VERIFY_TLS": "yes",
            "SCHEDULER_CA_BUNDLE": str(bundle),
            "SCHEDULER_CONNECT_TIMEOUT_S": "1.5",
            "SCHEDULER_READ_TIMEOUT_S": "20",
            "SCHEDULER_RESOURCES": "node-0*, node-1[0-2] ,",
            "SCHEDULER_GRANULARITY_S": "600",
        }
    )
    assert config is not None
    assert config.base_url == "https://broker:8001/am"
    assert config.account_name == "amazing.portal"
    assert config.token == "s3cret-token"
    assert (config.client_cert, config.client_key, config.ca_bundle) == (cert, key, bundle)
    assert config.timeouts_s == (1.5, 20.0)
    assert config.granularity_s == 600
    assert config.owned_resources == ("node-0*", "node-1[0-2]")
    owned = [
        name
        for name in ("node-01", "node-09", "node-10", "node-12", "node-13", "mobile-1")
        if config.owns(resource_name=name, is_fixed_node=name.startswith("node"))
    ]
    assert owned == ["node-01", "node-09", "node-10", "node-12"]
    # The token never shows in logs or error pages that print the settings.
    assert "s3cret" not in repr(config)
    session = OmfScheduler(config)._session
    assert session.headers["Authorization"] == "Bearer s3cret-token"
    assert session.cert == (str(cert), str(key))
    assert session.verify == str(bundle)


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"SCHEDULER_URL": "ftp://broker"}, "SCHEDULER_URL"),
        ({"SCHEDULER_URL": "http://"}, "SCHEDULER_URL"),
        ({"SCHEDULER_URL": "http://broker:99999"}, "SCHEDULER_URL"),
        ({"SCHEDULER_URL": "http://broker/?x=1"}, "SCHEDULER_URL"),
        ({"SCHEDULER_DIALECT": "fed4fire"}, "SCHEDULER_DIALECT"),
        ({"SCHEDULER_TOKEN": "two words"}, "SCHEDULER_TOKEN"),
        ({"SCHEDULER_TOKEN": "a", "SCHEDULER_TOKEN_FILE": "/x"}, "SCHEDULER_TOKEN_FILE"),
        ({"SCHEDULER_TOKEN_FILE": "/nonexistent/token"}, "SCHEDULER_TOKEN_FILE"),
        ({"SCHEDULER_CLIENT_CERT": "/nonexistent/cert.pem"}, "SCHEDULER_CLIENT_CERT"),
        ({"SCHEDULER_VERIFY_TLS": "maybe"}, "SCHEDULER_VERIFY_TLS"),
        ({"SCHEDULER_CONNECT_TIMEOUT_S": "soon"}, "SCHEDULER_CONNECT_TIMEOUT_S"),
        ({"SCHEDULER_CONNECT_TIMEOUT_S": "0"}, "SCHEDULER_CONNECT_TIMEOUT_S"),
        ({"SCHEDULER_READ_TIMEOUT_S": "nan"}, "SCHEDULER_READ_TIMEOUT_S"),
        ({"SCHEDULER_READ_TIMEOUT_S": "-1"}, "SCHEDULER_READ_TIMEOUT_S"),
        ({"SCHEDULER_GRANULARITY_S": "1.5"}, "SCHEDULER_GRANULARITY_S"),
        ({"SCHEDULER_GRANULARITY_S": "0"}, "SCHEDULER_GRANULARITY_S"),
    ],
)
def test_a_bad_value_is_an_error_naming_the_variable(changes: dict[str, str], named: str) -> None:
    env = {"SCHEDULER_URL": "https://broker:8001", **changes}
    with pytest.raises(ValueError, match=named):
        from_env(env)


def test_contradictory_tls_settings_are_errors(tmp_path: Path) -> None:
    pem = tmp_path / "x.pem"
    pem.write_text("pem")
    https = {"SCHEDULER_URL": "https://broker"}
    with pytest.raises(ValueError, match="SCHEDULER_CLIENT_KEY needs SCHEDULER_CLIENT_CERT"):
        from_env({**https, "SCHEDULER_CLIENT_KEY": str(pem)})
    with pytest.raises(ValueError, match="needs an https:// SCHEDULER_URL"):
        from_env({"SCHEDULER_URL": "http://broker", "SCHEDULER_CLIENT_CERT": str(pem)})
    with pytest.raises(ValueError, match="SCHEDULER_CA_BUNDLE is set but SCHEDULER_VERIFY_TLS"):
        from_env({**https, "SCHEDULER_VERIFY_TLS": "off", "SCHEDULER_CA_BUNDLE": str(pem)})
    with pytest.raises(ValueError, match="SCHEDULER_CA_BUNDLE"):
        from_env({**https, "SCHEDULER_CA_BUNDLE": str(tmp_path)})


def test_the_readme_documents_every_scheduler_variable() -> None:
    readme = (REPO / "README.md").read_text()
    source = (REPO / "bookings" / "scheduler" / "config.py").read_text()
    assert set(re.findall(r'"(SCHEDULER_[A-Z_]+)"', source)) == set(ENV_NAMES)
    for name in ENV_NAMES:
        if name.endswith("_FILE"):
            # Documented as the secret's row saying "_FILE accepted".
            row = next(line for line in readme.splitlines() if f"`{name[:-5]}`" in line)
            assert "`_FILE` accepted" in row, name
        else:
            assert f"`{name}`" in readme, f"README.md does not document {name}"


def _start_portal(env_changes: dict[str, str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("SCHEDULER_")}
    env.update({"DJANGO_SETTINGS_MODULE": "portal.settings", "AMAZING_VAR_DIR": str(tmp_path)})
    env.update(env_changes)
    check = (
        "import django; django.setup(); from django.conf import settings; "
        "print(settings.SCHEDULER and settings.SCHEDULER.base_url)"
    )
    return subprocess.run(
        [sys.executable, "-c", check], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )


def test_the_portal_reads_the_scheduler_settings_at_start(tmp_path: Path) -> None:
    configured = _start_portal({"SCHEDULER_URL": "http://broker:8710/"}, tmp_path)
    assert configured.returncode == 0, configured.stderr
    assert configured.stdout.strip() == "http://broker:8710"
    refused = _start_portal(
        {"SCHEDULER_URL": "http://broker:8710", "SCHEDULER_READ_TIMEOUT_S": "x"}, tmp_path
    )
    assert refused.returncode != 0
    assert "ImproperlyConfigured" in refused.stderr
    assert "SCHEDULER_READ_TIMEOUT_S" in refused.stderr
