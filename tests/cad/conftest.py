"""Models built once per test session: building is the slow part of these tests."""

from __future__ import annotations

import pytest

from cad import antenna_branch, bs_case, gps_mount, robot_case


@pytest.fixture(scope="session")
def bs() -> bs_case.BsCase:
    return bs_case.build()


@pytest.fixture(scope="session")
def robot() -> robot_case.RobotCase:
    return robot_case.build()


@pytest.fixture(scope="session")
def gps() -> gps_mount.GpsMount:
    return gps_mount.build()


@pytest.fixture(scope="session")
def branch() -> antenna_branch.AntennaBranch:
    return antenna_branch.build()
