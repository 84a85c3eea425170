"""The real agent application behind a real HTTP server, in process, with a hand-driven clock."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from werkzeug.serving import make_server

from basestation.app import create_app
from basestation.client import AgentClient
from basestation.config import AgentConfig
from basestation.runtime import AgentRuntime, get_runtime

TOKEN = "dispatch-test-token"
TICK_S = 0.05


@dataclass
class Agent:
    url: str
    runtime: AgentRuntime
    client: AgentClient

    def run_clock(self, from_s: float, to_s: float) -> None:
        """Advance the agent's clock from ``from_s`` to ``to_s`` one control tick at a time."""
        steps = round((to_s - from_s) / TICK_S)
        for k in range(steps + 1):
            self.runtime.manager.tick(from_s + k * TICK_S)


@pytest.fixture
def agent(tmp_path, settings) -> Iterator[Agent]:
    # The kinematic model: the clock is driven by hand here (see tests/basestation/conftest).
    config = AgentConfig(token=TOKEN, data_dir=tmp_path / "agent", robot="simple")
    app = create_app(config, start_control_loop=False)
    server = make_server("127.0.0.1", 0, app, threaded=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    settings.AGENT_TOKENS = {"default": TOKEN}
    url = f"http://127.0.0.1:{server.server_port}"
    try:
        yield Agent(url=url, runtime=get_runtime(app), client=AgentClient(url, TOKEN))
    finally:
        server.shutdown()
        thread.join()
        server.server_close()
        get_runtime(app).close()
