"""A write-only file object for the export's encoders (``encode``, ``mcap``):
the writers (pyarrow's, MCAP's) write into it, and the encoder takes what one
batch produced and hands it on, so memory is one batch's encoding.
"""

from __future__ import annotations


class Pieces:
    """A write-only file object that keeps what was written until taken."""

    closed = False

    def __init__(self) -> None:
        self._parts: list[bytes] = []
        self._size = 0

    def write(self, data) -> int:
        piece = bytes(data)
        self._parts.append(piece)
        self._size += len(piece)
        return len(piece)

    def tell(self) -> int:
        return self._size

    def flush(self) -> None:
        pass

    def close(self) -> None:  # the writer's close must not end our taking
        pass

    def take(self) -> bytes:
        out = b"".join(self._parts)
        self._parts = []
        return out
