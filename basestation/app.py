"""The agent's Flask application factory."""

from __future__ import annotations

from flask import Flask

from basestation.api import register_api
from basestation.config import AgentConfig
from basestation.robot import Robot
from basestation.runtime import EXTENSION_KEY, AgentRuntime

MAX_BODY_BYTES = 64 * 1024  # a 100-segment run is about 7 KiB; anything far larger is abuse


def create_app(
    config: AgentConfig | None = None,
    *,
    start_control_loop: bool = True,
    robot: Robot | None = None,
) -> Flask:
    """Build the agent: open the run store, start the control loop's process (which opens
    the robot).

    ``config`` defaults to :meth:`AgentConfig.from_env` (raises ``ConfigError``).
    With ``start_control_loop=False`` the run manager and ``robot`` live in this process and
    nothing moves until someone calls ``get_runtime(app).manager.tick(now_s)`` — how tests
    drive time. The caller owns the returned app's runtime and should call
    ``get_runtime(app).close()`` when done.
    """
    if config is None:
        config = AgentConfig.from_env()
    app = Flask(__name__)
    app.config.from_mapping(MAX_CONTENT_LENGTH=MAX_BODY_BYTES)
    # Flask's own knobs (FLASK_*) may still be set from the environment; the agent's
    # settings are AgentConfig's and come only from AGENT_*.
    app.config.from_prefixed_env()
    app.config["MAX_CONTENT_LENGTH"] = MAX_BODY_BYTES
    # Every answer is JSON: no automatic OPTIONS (no browser calls the agent; 405 instead),
    # no redirect from '//' to '/' (a 404 instead of an HTML redirect page).
    app.config["PROVIDE_AUTOMATIC_OPTIONS"] = False
    app.url_map.merge_slashes = False

    if start_control_loop:
        if robot is not None:
            raise ValueError("the control loop's process builds its own robot")
        runtime = AgentRuntime.open_with_loop_process(config)
    else:
        runtime = AgentRuntime.open(config, robot=robot)
    app.extensions[EXTENSION_KEY] = runtime
    register_api(app)
    return app
