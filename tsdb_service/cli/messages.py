"""Library messages made into one readable line for an ``error:`` line.

libpq words a refused connection in two lines, the second a question
("Is the server running on that host and accepting TCP/IP connections?");
folded into one line by the store's and the importer's messages, the two
ran together as "Connection refused Is the server ...". ``readable`` makes
that question a parenthesis. The commands pass every operator error through
it, whichever part of the code worded it.
"""

from __future__ import annotations

import re

_LIBPQ_QUESTION = re.compile(r"\s+Is the server (running [^?]*)\?")


def readable(message: str) -> str:
    """``message`` on one line, libpq's follow-up question as a parenthesis."""
    return _LIBPQ_QUESTION.sub(r" (is the server \1?)", " ".join(message.split()))
