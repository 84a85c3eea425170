"""Domain events: the outbox other software follows.

Every change another program may want to know of (a reservation made, moved, decided or
cancelled, through whichever door; a run's every state) is written as an :class:`Event` row
in the same transaction as the change itself (``services.event_record``), so an event exists
exactly when its change was committed. Rows are numbered once committed: the sequencer
(``services.events_sequence``) gives each its ``position`` (one order for everything, the
order of the commits) and its subject's ``seq`` (1, 2, 3… per reservation, per run), under a
lock, so that a reader following ``position`` never skips a row that commits late.

Readers: ``GET /api/v1/events/?after=N`` (a user's own events, long-polled; staff also the
events of no one's), ``amazing events --follow``. The types and their payloads are listed in
``catalogue.py``, with a version each.
"""
