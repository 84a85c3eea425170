"""Names the embedded setup gives its robots, shared by the launcher (before Django starts) and
the demo data (``bookings/management/commands/demo_setup.py``). Plain Python."""

# The second simulated robot of ``make run ROBOTS=2``: its resource and its agent token's name.
SECOND_ROBOT = "mobile-2"
