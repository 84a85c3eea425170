"""A stand-in for the testbed's omf_sfa broker, served by ``python -m
bookings.scheduler.standin``; ``broker`` holds it (its docstring says what it does)."""

from bookings.scheduler.standin.broker import (
    ENV_PREFIX,
    ConfigError,
    StandinConfig,
    build_parser,
    close_app,
    config_from,
    create_app,
)

__all__ = [
    "ENV_PREFIX",
    "ConfigError",
    "StandinConfig",
    "build_parser",
    "close_app",
    "config_from",
    "create_app",
]
