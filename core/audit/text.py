"""Text as PostgreSQL can keep it in an audit row."""

from __future__ import annotations

import re

# PostgreSQL's text and jsonb hold neither NUL nor a UTF-16 surrogate on its own; a JSON
# body can carry both (``\u0000``, ``\ud800``).
_UNSTORABLE = re.compile("[\x00\ud800-\udfff]")


def storable_text(text: str) -> str:
    """``text`` with each character PostgreSQL cannot store replaced by U+FFFD, so that an
    audit row keeps every other character (and the length) of what was sent."""
    return _UNSTORABLE.sub("\ufffd", text)
