"""The one list of the system's processes that ``make run`` and the test stack both start."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from portal.processes import ProcessSpec, system_processes

REPO = Path(__file__).resolve().parents[2]
PYTHON = "/opt/amazing/bin/python"


def _processes(**options: Any) -> dict[str, ProcessSpec]:
    specs = system_processes(
        python=PYTHON, portal_port=8123, streams_port=8124, agent_port=8765,
        var_dir=Path("/srv/amazing/var"), **options,
    )  # fmt: skip
    return {spec.name: spec for spec in specs}


def _option(argv: tuple[str, ...], flag: str) -> str:
    return argv[argv.index(flag) + 1]


def test_it_lists_agent_web_workers_collector_and_beat_in_start_order_all_on_the_given_python():
    processes = _processes()
    assert list(processes) == ["agent", "web", "streams", "worker", "mail", "collector", "beat"]
    for spec in processes.values():
        assert spec.argv[0] == PYTHON
        assert spec.env == {}


def test_runs_and_mail_have_a_worker_each_so_a_mail_backlog_cannot_delay_a_run():
    processes = _processes()
    worker, mail = processes["worker"].argv, processes["mail"].argv
    assert (_option(worker, "--queues"), _option(mail, "--queues")) == ("runs", "mail")
    assert _option(worker, "--hostname") != _option(mail, "--hostname")


def test_a_second_robot_is_an_agent_of_its_own_on_its_own_rail_store_and_token():
    processes = _processes(second_agent_port=8766)
    assert list(processes) == [
        "agent", "agent-2", "web", "streams", "worker", "mail", "collector", "beat",
    ]  # fmt: skip
    second = processes["agent-2"]
    assert _option(second.argv, "--port") == "8766"
    assert second.env["AGENT_RESOURCE"] == "mobile-2"
    assert second.env["AGENT_DATA_DIR"] == "/srv/amazing/var/agent-2"
    assert second.env["AGENT_TOKEN_FILE"] == "/srv/amazing/var/agent-2-token"
    assert second.env["AGENT_TOKEN"] == ""  # the first agent's token is not inherited
    assert Path(second.env["AGENT_RAIL_FILE"]).is_file()
    assert "AGENT_RAIL_FILE" not in processes["agent"].env


def test_the_ports_and_the_host_go_to_the_agent_and_the_web_servers():
    processes = _processes(host="192.0.2.10")
    agent, web, streams = (processes[name].argv for name in ("agent", "web", "streams"))
    assert agent[1:3] == ("-m", "basestation")
    assert (_option(agent, "--port"), _option(agent, "--host")) == ("8765", "192.0.2.10")
    assert _option(web, "--bind") == "192.0.2.10:8123"
    assert (_option(streams, "--port"), _option(streams, "--host")) == ("8124", "192.0.2.10")
    for other in ("worker", "mail", "beat"):
        assert "8123" not in processes[other].argv
        assert "8765" not in processes[other].argv


def test_pages_and_api_are_served_by_wsgi_threads_and_the_streams_by_the_asgi_server():
    """No bridge between an event loop and the synchronous views; no thread per stream."""
    web, streams = _processes()["web"].argv, _processes()["streams"].argv
    assert web[1:3] == ("-m", "portal.serve")
    assert streams[1:3] == ("-m", "uvicorn")
    assert "portal.asgi:application" in streams


def test_the_wsgi_server_takes_its_processes_and_threads_from_the_settings(tmp_path):
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("DJANGO_", "WEB_", "DATABASE_", "REDIS_", "CELERY_"))
    }
    env.update({"DJANGO_DEBUG": "1", "AMAZING_VAR_DIR": str(tmp_path), "WEB_WORKERS": "3"})
    code = (
        "from portal.serve import server_options as o; "
        "c = o(['--bind', '127.0.0.1:8123']); "
        "print(c['target'], c['workers'], c['blocking_threads'], c['respawn_failed_workers'])"
    )
    shown = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )
    assert shown.stdout.split() == ["portal.wsgi:application", "3", "8", "True"], shown.stderr


def test_the_host_is_loopback_unless_given():
    processes = _processes()
    assert _option(processes["agent"].argv, "--host") == "127.0.0.1"
    assert _option(processes["web"].argv, "--bind") == "127.0.0.1:8123"
    assert _option(processes["streams"].argv, "--host") == "127.0.0.1"


def test_the_access_log_can_be_turned_off():
    assert "--access-log" in _processes()["web"].argv
    assert "--access-log" not in _processes(access_log=False)["web"].argv
    assert "--no-access-log" not in _processes()["streams"].argv
    assert "--no-access-log" in _processes(access_log=False)["streams"].argv


def test_the_worker_and_beat_run_the_portals_celery_app_with_beats_state_under_var_dir():
    processes = _processes(worker_concurrency=2, log_level="DEBUG")
    worker, beat = processes["worker"].argv, processes["beat"].argv
    assert worker[1:6] == ("-m", "celery", "-A", "portal", "worker")
    assert (_option(worker, "--concurrency"), _option(worker, "--loglevel")) == ("2", "DEBUG")
    assert beat[1:6] == ("-m", "celery", "-A", "portal", "beat")
    assert _option(beat, "--schedule") == "/srv/amazing/var/celerybeat-schedule"
    assert _option(beat, "--loglevel") == "DEBUG"


def test_the_collector_is_the_portals_collect_live_command():
    argv = _processes()["collector"].argv
    assert argv[1].endswith("manage.py")
    assert argv[2:] == ("collect_live",)


def test_the_list_is_built_without_setting_up_django():
    # Production settings without their secrets fail on import: the list must not need them.
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DJANGO_", "AGENT_"))}
    script = (
        "import sys\n"
        "from pathlib import Path\n"
        "from portal.processes import system_processes\n"
        "specs = system_processes(\n"
        "    python='py', portal_port=1, streams_port=3, agent_port=2, var_dir=Path('v')\n"
        ")\n"
        "print([s.name for s in specs], 'django.apps' in sys.modules, 'django.db' in sys.modules)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=60,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    names = "['agent', 'web', 'streams', 'worker', 'mail', 'collector', 'beat']"
    assert result.stdout.strip() == f"{names} False False"
