"""pytest-xdist's file-by-file scheduling, made to end the run when a worker dies.

Loaded with ``-p`` (pyproject.toml). pytest-xdist 3.8's ``LoadFileScheduling`` puts a dead
worker's whole workload back on the queue, the files it had finished too; a finished file
handed out again sends a worker nothing to run, so it never reports back, is never given more,
and the session waits for it forever (pytest-xdist issues 1323, 1327 and 1378). A worker that
died once (a segmentation fault) turned a red run into one that hung until the CI's limit,
without the summary that says what failed. It also ran the test the worker died on again,
which had already been reported failed.

Here only the files with tests still to run go back on the queue, without the test the
worker died on, and a worker never waits with one test in hand (a worker runs its last test
only once it knows there is no next) while the queue has work or the session is over.
"""

from __future__ import annotations

import pytest
from xdist.remote import Producer
from xdist.scheduler import LoadFileScheduling
from xdist.workermanage import WorkerController


class LoadFileAfterCrashScheduling(LoadFileScheduling):
    def remove_node(self, node: WorkerController) -> str | None:
        workload = self.assigned_work.pop(node)
        crashed = next(
            (nodeid for unit in workload.values() for nodeid, done in unit.items() if not done),
            None,
        )
        if crashed is None:  # a worker that finished its work and stopped
            return None
        for scope, unit in workload.items():
            if crashed in unit:
                unit[crashed] = True  # reported failed by xdist; not run again
            if not all(unit.values()):
                self.workqueue[scope] = unit
        for other in self.assigned_work:
            self._reschedule(other)
        return crashed

    def _reschedule(self, node: WorkerController) -> None:
        super()._reschedule(node)
        # A replacement worker given a one-test file would wait for a second test forever.
        while not node.shutting_down and self._pending_of(self.assigned_work[node]) < 2:
            if not self.workqueue:
                node.shutdown()
                return
            self._assign_work_unit(node)


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Producer) -> LoadFileScheduling | None:
    if config.getvalue("dist") != "loadfile":
        return None
    return LoadFileAfterCrashScheduling(config, log)
