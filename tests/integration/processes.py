"""What only the tests ask of processes; starting them is ``bench/stack.py``'s."""

from __future__ import annotations

import os
from pathlib import Path


def processes_matching_env(key: str, value: str) -> list[int]:
    """PIDs of live processes whose environment holds ``key=value`` (Linux /proc)."""
    needle = f"{key}={value}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            environ = (entry / "environ").read_bytes().split(b"\0")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if needle in environ and state != "Z":
            found.append(int(entry.name))
    return found
