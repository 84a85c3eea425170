"""The collector: a process that follows every staged or running run and stores its samples
the moment the agent has them, so a live page sees a sample within a fraction of a second.

``manage.py collect_live`` runs it (``portal/processes.py`` lists it for ``make run`` and the
test stack). The main thread scans the database every ``COLLECTOR_SCAN_INTERVAL_S`` for runs
to follow (:func:`collection.runs_to_follow`) and starts one thread per run; each thread
long-polls the run's agent (:func:`collection.run_follow_page`), stores what arrives and so
announces it on the live bus. A thread ends when the run is no longer staged or running
here, or when the agent has ended it — then it runs the final check at once
(:func:`collection.run_collect`), which the sweep would otherwise do a moment later.

Why a process of its own and threads, not Celery tasks: following a run is waiting on the
agent for the whole run; as tasks those waits would hold the runs worker's slots (one per
robot), and staging and the sweeps would queue behind them.

Nothing here is needed for correctness: the sweep still collects every active run, resuming
after the last stored sample whoever stored it, and ingest is idempotent by sequence number.
A collector killed mid-run costs the pages their promptness until it is back, never a sample.
"""

from __future__ import annotations

import logging
import threading

from django.conf import settings
from django.db import close_old_connections, connection
from django.utils import timezone

from basestation.client import AgentClient, AgentError
from portal.runs.agents import agent_client_for
from portal.runs.models import Run
from portal.runs.services import collection

logger = logging.getLogger(__name__)

# After a failed long-poll (agent down, run not staged there yet), wait this long before the
# next: an agent that is down is not hammered, and one back is followed again within it.
RETRY_S = 1.0


class Collector:
    def __init__(self, *, scan_interval_s: float, wait_s: int) -> None:
        self.scan_interval_s = scan_interval_s
        self.wait_s = wait_s
        self.stopping = threading.Event()
        # Set from a signal handler: a plain attribute, which the scan loop turns into
        # ``stopping`` (an Event's lock is not reentrant, and a second signal arriving while
        # the handler of the first is inside ``Event.set`` would hang the process).
        self.stop_requested = False
        self._followers: dict[int, threading.Thread] = {}

    def stop(self) -> None:
        self.stopping.set()

    def request_stop(self) -> None:
        """Stop soon: safe to call from a signal handler (the scan loop stops the rest)."""
        self.stop_requested = True

    @property
    def following(self) -> list[int]:
        return [run_id for run_id, thread in self._followers.items() if thread.is_alive()]

    def run(self) -> None:
        """Scan and follow until :meth:`stop`."""
        logger.info(
            "collector ready: scanning every %g s, long-polls of %d s",
            self.scan_interval_s,
            self.wait_s,
        )
        while not self.stopping.is_set():
            if self.stop_requested:
                self.stopping.set()
                break
            self.scan()
            self.stopping.wait(self.scan_interval_s)
        for thread in self._followers.values():
            # A thread in a long-poll ends with it; nothing it holds is lost if cut short.
            thread.join(timeout=1.0)

    def scan(self) -> None:
        """Start a follower for each run to follow that has none."""
        close_old_connections()
        try:
            due = list(collection.runs_to_follow(now=timezone.now()).values_list("pk", flat=True))
        except Exception:
            logger.exception("collector: cannot read the runs to follow")
            connection.close()
            return
        self._followers = {
            run_id: thread for run_id, thread in self._followers.items() if thread.is_alive()
        }
        for run_id in due:
            if run_id not in self._followers:
                thread = threading.Thread(
                    target=self.follow, args=(run_id,), name=f"follow-run-{run_id}", daemon=True
                )
                self._followers[run_id] = thread
                thread.start()

    def follow(self, run_id: int) -> None:
        """Store the run's samples as the agent stores them, until it ends."""
        client: AgentClient | None = None
        taken_up = False
        try:
            while not self.stopping.is_set():
                # Each round from the database: the sweep may have stored some meanwhile,
                # or ended the run.
                run = Run.objects.select_related("resource").filter(pk=run_id).first()
                if run is None or run.state not in collection.RUN_FOLLOWED_STATES:
                    return
                if client is None:
                    client = agent_client_for(run.resource)
                if not taken_up:
                    # A collector killed after storing samples and before announcing them
                    # left them unannounced: the pages hear of them now, once.
                    collection.samples_announce_missed(run=run)
                    taken_up = True
                try:
                    page = collection.run_follow_page(run=run, client=client, wait_s=self.wait_s)
                except AgentError as exc:
                    logger.info("run %s: not followed for now: %s", run_id, exc)
                    self.stopping.wait(RETRY_S)
                    continue
                if not page.agent_active and not page.more:
                    # Ended on the agent, every sample stored: check and close it now.
                    try:
                        collection.run_collect(run_id=run_id)
                    except AgentError as exc:
                        logger.info("run %s: final check left to the sweep: %s", run_id, exc)
                    return
        except Exception:
            # The next scan starts a new follower; meanwhile the sweep collects.
            logger.exception("run %s: follower stopped", run_id)
            self.stopping.wait(RETRY_S)
        finally:
            if client is not None:
                client.close()
            connection.close()


def collector_from_settings() -> Collector:
    return Collector(
        scan_interval_s=settings.COLLECTOR_SCAN_INTERVAL_S, wait_s=settings.COLLECTOR_WAIT_S
    )
