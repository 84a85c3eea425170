"""The generated sections of the docs the benchmarks and the soak write: a block between two
markers, replaced in place, or added at the end the first time."""

from __future__ import annotations

from pathlib import Path


def write_section(path: Path, *, begin: str, end: str, body: str, title: str) -> None:
    """Put ``body`` between ``begin`` and ``end`` in ``path`` (a new file starts with ``title``)."""
    text = path.read_text() if path.exists() else f"{title}\n"
    block = f"{begin}\n{body.rstrip()}\n{end}"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    path.write_text(text)
