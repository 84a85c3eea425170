"""The system's processes and their command lines, in one list.

``make run`` (``portal.launcher``) and the integration and browser tests' stack
(``tests/integration/stack.py``) both start the processes this module lists, so whatever runs
in one runs in the other. Each process has its own small builder; an optional process gets a
flag of ``system_processes`` that adds it.

No Django here: the launcher builds the list before Django is set up.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from core.fleet import SECOND_ROBOT

DEFAULT_HOST = "127.0.0.1"
REPO = Path(__file__).resolve().parent.parent
# Celery queues, each with its own worker: a backlog of mail never delays a run.
RUNS_QUEUE = "runs"
MAIL_QUEUE = "mail"
# The rail the second simulated robot (make run with ROBOTS=2) drives, beside the first.
SECOND_RAIL_FILE = REPO / "basestation" / "telemetry" / "second_rail.json"


@dataclass(frozen=True)
class ProcessSpec:
    """One process: its name (as in logs), its command line, and what it adds to the environment.

    ``env`` holds only what differs from the environment every process shares.
    """

    name: str
    argv: tuple[str, ...]
    env: Mapping[str, str] = field(default_factory=dict)


def agent_process(*, python: str, port: int, host: str = DEFAULT_HOST) -> ProcessSpec:
    """The base-station agent with the simulated robot (``AGENT_*`` from the environment)."""
    return ProcessSpec("agent", (python, "-m", "basestation", "--host", host, "--port", str(port)))


def second_agent_process(
    *, python: str, port: int, data_dir: Path, token_file: Path, host: str = DEFAULT_HOST
) -> ProcessSpec:
    """A second agent with its own simulated robot on its own rail, store and token."""
    return ProcessSpec(
        "agent-2",
        (python, "-m", "basestation", "--host", host, "--port", str(port)),
        {
            "AGENT_RESOURCE": SECOND_ROBOT,
            "AGENT_DATA_DIR": str(data_dir),
            "AGENT_RAIL_FILE": str(SECOND_RAIL_FILE),
            # Its own token: the first agent's (by value or by file) is not its.
            "AGENT_TOKEN": "",
            "AGENT_TOKEN_FILE": str(token_file),
        },
    )


# An open live stream (Server-Sent Events) never ends by itself: on shutdown the server
# waits this long for requests, then closes the streams (the pages reconnect).
STREAMS_GRACEFUL_SHUTDOWN_S = 3


def web_process(
    *, python: str, port: int, host: str = DEFAULT_HOST, access_log: bool = True
) -> ProcessSpec:
    """The pages and the API on the WSGI server (``portal/serve.py``)."""
    argv = [python, "-m", "portal.serve", "--bind", f"{host}:{port}"]
    if access_log:
        argv.append("--access-log")
    return ProcessSpec("web", tuple(argv))


def streams_process(
    *, python: str, port: int, host: str = DEFAULT_HOST, access_log: bool = True
) -> ProcessSpec:
    """The live streams (``/live/``) on the ASGI server: an open stream is a coroutine waiting
    on the bus, not a thread. The pages reach it on its own port of the same host
    (``LIVE_STREAM_PORT``) or through a proxy on their own origin."""
    argv = [python, "-m", "uvicorn", "portal.asgi:application", "--host", host]
    argv += ["--port", str(port), "--timeout-graceful-shutdown", str(STREAMS_GRACEFUL_SHUTDOWN_S)]
    # The client's address is the portal's to read (TRUSTED_PROXY_COUNT), not the server's.
    argv.append("--no-proxy-headers")
    if not access_log:
        argv.append("--no-access-log")
    return ProcessSpec("streams", tuple(argv))


def worker_process(
    *,
    python: str,
    concurrency: int = 4,
    log_level: str = "INFO",
    queue: str = RUNS_QUEUE,
    name: str = "worker",
) -> ProcessSpec:
    """A Celery worker for one queue. Threads, not forks: the tasks wait on the network,
    not the CPU."""
    return ProcessSpec(
        name,
        (
            python,
            "-m",
            "celery",
            "-A",
            "portal",
            "worker",
            "--loglevel",
            log_level,
            "--pool",
            "threads",
            "--concurrency",
            str(concurrency),
            "--queues",
            queue,
            # Its own name: two workers on one host must not share one.
            "--hostname",
            f"{name}@%h",
            # Nothing to synchronise with at start or to chat with afterwards.
            "--without-mingle",
            "--without-gossip",
        ),
    )


def mail_worker_process(*, python: str, log_level: str = "INFO") -> ProcessSpec:
    """The worker that sends e-mail, apart from the one that stages and collects runs."""
    return worker_process(
        python=python, concurrency=2, log_level=log_level, queue=MAIL_QUEUE, name="mail"
    )


def collector_process(*, python: str) -> ProcessSpec:
    """The collector (``portal/runs/collector.py``): follows running runs on their agents and
    stores each sample as soon as it is stored there, for the live pages."""
    return ProcessSpec("collector", (python, str(REPO / "manage.py"), "collect_live"))


def beat_process(*, python: str, schedule_file: Path, log_level: str = "INFO") -> ProcessSpec:
    """Celery beat, keeping its schedule state in ``schedule_file``."""
    return ProcessSpec(
        "beat",
        (
            python,
            "-m",
            "celery",
            "-A",
            "portal",
            "beat",
            "--loglevel",
            log_level,
            "--schedule",
            str(schedule_file),
        ),
    )


def standin_process(
    *, python: str, port: int, db_path: Path, host: str = DEFAULT_HOST, test_control: bool = False
) -> ProcessSpec:
    """The stand-in for the testbed's scheduler (``bookings/scheduler/standin/``), the
    process named ``scheduler``: the embedded default of ``make run``, which then owns the 24
    fixed nodes, and the testbed scheduler of the integration tests (with its test-only
    control endpoints)."""
    argv = [python, "-m", "bookings.scheduler.standin", "--host", host, "--port", str(port)]
    argv += ["--db", str(db_path)]
    if test_control:
        argv.append("--test-control")
    return ProcessSpec("scheduler", tuple(argv))


def system_processes(
    *,
    python: str,
    portal_port: int,
    streams_port: int,
    agent_port: int,
    var_dir: Path,
    host: str = DEFAULT_HOST,
    access_log: bool = True,
    worker_concurrency: int = 4,
    log_level: str = "INFO",
    standin_port: int | None = None,
    standin_test_control: bool = False,
    second_agent_port: int | None = None,
) -> list[ProcessSpec]:
    """The agent, the web server (pages and API), the streams server, the Celery workers
    (runs, mail), the collector and beat, in the order to start them.

    ``python`` runs every process; ``host`` is the address the agents and the web server
    listen on; ``var_dir`` holds local state (beat's schedule, the second agent's store and
    token, the stand-in's leases); ``access_log`` turns the web server's line per request on
    or off; ``second_agent_port`` adds a second agent with its own simulated robot there;
    ``standin_port`` adds the stand-in scheduler first (the portal's ``SCHEDULER_URL`` must
    then point at it).
    """
    processes = [
        agent_process(python=python, port=agent_port, host=host),
        web_process(python=python, port=portal_port, host=host, access_log=access_log),
        streams_process(python=python, port=streams_port, host=host, access_log=access_log),
        worker_process(python=python, concurrency=worker_concurrency, log_level=log_level),
        mail_worker_process(python=python, log_level=log_level),
        collector_process(python=python),
        beat_process(
            python=python, schedule_file=var_dir / "celerybeat-schedule", log_level=log_level
        ),
    ]
    if second_agent_port is not None:
        processes.insert(
            1,
            second_agent_process(
                python=python,
                port=second_agent_port,
                host=host,
                data_dir=var_dir / "agent-2",
                token_file=var_dir / "agent-2-token",
            ),
        )
    if standin_port is not None:
        processes.insert(
            0,
            standin_process(
                python=python,
                port=standin_port,
                db_path=var_dir / "scheduler-standin.sqlite3",
                host=host,
                test_control=standin_test_control,
            ),
        )
    return processes
