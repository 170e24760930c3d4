"""Text every backend can hold: no NUL character, anywhere in a document.

PostgreSQL's ``text`` cannot hold U+0000 (nor can ``jsonb``, which the
value paths of queries use), while DuckDB can: a notification with a NUL in
a Text value was stored on DuckDB, and on PostgreSQL failed its write again
and again (503 over HTTP, a message stuck at the head of MQTT's queue). So
no backend accepts one: a NUL anywhere in a notification (a value, metadata,
a name, an envelope's headers) refuses it at parse time, it is kept in the
rejected store, and a DuckDB store can always be copied to PostgreSQL.

In JSON a NUL can only be written ``\\u0000``, so a body without those
six bytes is checked by one ``bytes`` search; only one with them is walked.
"""

from __future__ import annotations

from typing import Any

NUL_RULE = "no text may contain the NUL character (U+0000): PostgreSQL cannot store it, so no backend accepts it"
_ESCAPED_NUL = b"\\u0000"
_MAX_PATH = 200


def nul_path(raw: bytes, doc: Any) -> str | None:
    """Where the first NUL is in ``doc`` (the JSON ``raw`` decodes to), as
    ``data[0].name.value``, or None when it has none."""
    if _ESCAPED_NUL not in raw:
        return None
    stack: list[tuple[str, Any]] = [("", doc)]
    while stack:
        path, node = stack.pop()
        if type(node) is str:
            if "\0" in node:
                return path or "the document"
        elif type(node) is dict:
            for key, value in reversed(list(node.items())):
                if "\0" in key:
                    return f"a member name in {path or 'the document'}"
                stack.append((f"{path}.{key}" if path else key, value))
        elif type(node) is list:
            stack.extend((f"{path}[{i}]", item) for i, item in reversed(list(enumerate(node))))
    return None


def nul_problem(raw: bytes, doc: Any) -> str | None:
    """A sentence saying where ``doc`` holds a NUL and why that is refused, or None."""
    path = nul_path(raw, doc)
    if path is None:
        return None
    shown = path.replace("\0", "\\u0000")[:_MAX_PATH]
    return f"{shown} holds the NUL character; {NUL_RULE}"
