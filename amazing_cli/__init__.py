"""``amazing``: the AMazING testbed's public REST API from a terminal.

Built on the API alone (``/api/v1/``, described at ``/api/schema/``): no Django, nothing of the
portal. ``docs/cli.md`` is the manual.
"""
