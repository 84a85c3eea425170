from __future__ import annotations

import os
from pathlib import Path

import pytest

from basestation.config import AUTO_CPU, AgentConfig, ConfigError
from basestation.loop_process import pick_cpu

TOKEN = "a-long-enough-token"


def test_it_reads_defaults_when_only_the_token_is_set() -> None:
    config = AgentConfig.from_env({"AGENT_TOKEN": TOKEN})
    assert config.token == TOKEN
    assert config.data_dir == Path("./var/agent")
    assert config.control_hz == 20.0
    assert config.max_velocity_mps == 2.0
    assert config.max_accel_mps2 == 1.0
    assert config.rail_length_m == 120.0
    assert config.resource == "mobile-1"
    assert config.low_battery_v == 50.0
    assert config.min_free_disk_mb == 200.0
    assert config.retention_days == 90.0
    assert config.retention_s == 90 * 86_400.0
    assert config.cpu_temp_path == Path("/sys/class/thermal/thermal_zone0/temp")


def test_it_reads_every_variable() -> None:
    config = AgentConfig.from_env(
        {
            "AGENT_TOKEN": TOKEN,
            "AGENT_DATA_DIR": "/srv/agent",
            "AGENT_CONTROL_HZ": "10",
            "AGENT_MAX_VELOCITY_MPS": "1.5",
            "AGENT_MAX_ACCEL_MPS2": "0.5",
            "AGENT_RAIL_LENGTH_M": "250",
            "AGENT_RESOURCE": "mobile-2",
            "AGENT_LOW_BATTERY_V": "52.5",
            "AGENT_MIN_FREE_DISK_MB": "50",
            "AGENT_RETENTION_DAYS": "30",
            "AGENT_CPU_TEMP_PATH": "/sys/class/thermal/thermal_zone1/temp",
        }
    )
    assert config.data_dir == Path("/srv/agent")
    assert config.control_hz == 10.0
    assert config.max_velocity_mps == 1.5
    assert config.max_accel_mps2 == 0.5
    assert config.rail_length_m == 250.0
    assert config.resource == "mobile-2"
    assert config.low_battery_v == 52.5
    assert config.min_free_disk_mb == 50.0
    assert config.retention_days == 30.0
    assert config.cpu_temp_path == Path("/sys/class/thermal/thermal_zone1/temp")


def test_zero_switches_the_battery_disk_and_retention_checks_off() -> None:
    config = AgentConfig.from_env(
        {
            "AGENT_TOKEN": TOKEN,
            "AGENT_LOW_BATTERY_V": "0",
            "AGENT_MIN_FREE_DISK_MB": "0",
            "AGENT_RETENTION_DAYS": "0",
        }
    )
    assert (config.low_battery_v, config.min_free_disk_mb) == (0.0, 0.0)
    assert config.retention_s is None


def test_it_reads_the_token_from_a_file(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n", encoding="utf-8")
    config = AgentConfig.from_env({"AGENT_TOKEN_FILE": str(token_file)})
    assert config.token == TOKEN


def test_it_refuses_to_start_without_a_token() -> None:
    with pytest.raises(ConfigError, match="AGENT_TOKEN_SHA256 must be set"):
        AgentConfig.from_env({})


def test_it_refuses_an_empty_token() -> None:
    with pytest.raises(ConfigError, match="AGENT_TOKEN"):
        AgentConfig.from_env({"AGENT_TOKEN": ""})


def test_it_refuses_a_missing_token_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="AGENT_TOKEN_FILE: cannot read"):
        AgentConfig.from_env({"AGENT_TOKEN_FILE": str(tmp_path / "absent")})


def test_it_refuses_an_empty_token_file(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text("\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"AGENT_TOKEN_FILE.*empty"):
        AgentConfig.from_env({"AGENT_TOKEN_FILE": str(token_file)})


def test_it_refuses_both_token_sources(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="only one of"):
        AgentConfig.from_env({"AGENT_TOKEN": TOKEN, "AGENT_TOKEN_FILE": str(tmp_path / "t")})


def test_it_refuses_a_token_with_spaces() -> None:
    with pytest.raises(ConfigError, match="AGENT_TOKEN must be printable ASCII"):
        AgentConfig.from_env({"AGENT_TOKEN": "two words"})


@pytest.mark.parametrize(
    ("variable", "value"),
    [
        ("AGENT_CONTROL_HZ", "fast"),
        ("AGENT_CONTROL_HZ", "0"),
        ("AGENT_CONTROL_HZ", "nan"),
        ("AGENT_MAX_VELOCITY_MPS", "-1"),
        ("AGENT_MAX_VELOCITY_MPS", "inf"),
        ("AGENT_MAX_ACCEL_MPS2", "0"),
        ("AGENT_RAIL_LENGTH_M", "1e9"),
        ("AGENT_RAIL_LENGTH_M", "12 m"),
        ("AGENT_RESOURCE", "  "),
        ("AGENT_LOW_BATTERY_V", "-1"),
        ("AGENT_LOW_BATTERY_V", "low"),
        ("AGENT_MIN_FREE_DISK_MB", "-5"),
        ("AGENT_MIN_FREE_DISK_MB", "nan"),
        ("AGENT_RETENTION_DAYS", "0.5"),
        ("AGENT_RETENTION_DAYS", "-1"),
        ("AGENT_RETENTION_DAYS", "forever"),
        ("AGENT_RETENTION_DAYS", "inf"),
        ("AGENT_CONTROL_CPU", "-1"),
        ("AGENT_CONTROL_CPU", "last"),
        ("AGENT_CONTROL_CPU", "5000"),
    ],
)
def test_it_names_the_variable_holding_a_bad_value(variable: str, value: str) -> None:
    with pytest.raises(ConfigError, match=variable):
        AgentConfig.from_env({"AGENT_TOKEN": TOKEN, variable: value})


@pytest.mark.parametrize(
    ("value", "expected"), [("", AUTO_CPU), ("none", None), ("NONE", None), ("1", 1)]
)
def test_it_reads_the_control_loops_cpu(value: str, expected: int | None) -> None:
    config = AgentConfig.from_env({"AGENT_TOKEN": TOKEN, "AGENT_CONTROL_CPU": value})
    assert config.control_cpu == expected


def test_the_loop_is_pinned_to_the_last_allowed_cpu_or_as_asked() -> None:
    allowed = sorted(os.sched_getaffinity(0))
    assert pick_cpu(AUTO_CPU) == (allowed[-1] if len(allowed) >= 2 else None)
    assert pick_cpu(None) is None
    assert pick_cpu(0) == 0


def test_it_never_shows_the_token_in_its_repr() -> None:
    assert TOKEN not in repr(AgentConfig(token=TOKEN))
