"""The group committer sets a poison operation aside instead of failing it with 503 for ever (issue 37, finding 2).

The committer's own rules, with an appender of ours that refuses one
operation (the real databases refusing content are in
``test_poison_messages.py``): a group that fails is retried one operation
at a time; one that fails every time is ``NotStorable`` (4xx: its caller
keeps it in the rejected store) when the appender says the content is at
fault, or when the operations beside it committed (the database evidently
takes writes); alone and undiagnosed it stays ``Unavailable`` (503).
"""

from __future__ import annotations

import threading
from datetime import UTC, datetime
from typing import ClassVar

import pytest

from tsdb_service.core.errors import NotStorable, Unavailable
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.write.appender import Appender
from tsdb_service.write.committer import GroupCommitter
from tsdb_service.write.ops import AppendSamples


def op(tenant: str) -> AppendSamples:
    """Samples: the committer groups them (other ops commit one at a time)."""
    sample = AttrSample("n", "Number", Kind.NUMBER, num=1.0)
    return AppendSamples([EntitySample(tenant, "/", "E", "T", datetime.now(UTC), [sample])])


class Refusing(Appender):
    """Commits everything but a staged op of tenant ``poison``; an op of
    tenant ``hold`` waits for ``release`` (the writer is busy meanwhile)."""

    committed: ClassVar[list[str]] = []
    release = threading.Event()

    def __init__(self, diagnosed: bool):
        self.diagnosed = diagnosed
        self.staged: list[str] = []

    def stage(self, op) -> None:
        self.staged.append(op.entities[0].tenant)

    def commit(self) -> None:
        if "hold" in self.staged:
            Refusing.release.wait(10)
        if "poison" in self.staged:
            raise RuntimeError("the value does not fit")
        Refusing.committed += self.staged
        self.staged = []

    def rollback(self) -> None:
        self.staged = []

    def refuses(self, exc: BaseException) -> bool:
        return self.diagnosed


@pytest.mark.parametrize("diagnosed", [True, False])
def test_a_poison_op_among_others_is_set_aside_and_the_others_commit(diagnosed):
    Refusing.committed = []
    Refusing.release.clear()
    committer = GroupCommitter(lambda: Refusing(diagnosed))
    committer.start()
    try:
        holding = threading.Thread(target=committer.submit_sync, args=([op("hold")],))
        holding.start()  # the writer is busy with it: the next three are queued as one group
        while committer.queue_depth:
            threading.Event().wait(0.01)
        threading.Timer(0.2, Refusing.release.set).start()
        with pytest.raises(NotStorable, match="the value does not fit"):
            committer.submit_sync([op("a"), op("poison"), op("b")])
        holding.join()
    finally:
        committer.close()
    assert sorted(Refusing.committed) == ["a", "b", "hold"]
    assert committer.poisoned == 1 and committer.last_poison is not None


def test_a_lone_undiagnosed_failure_stays_unavailable():
    committer = GroupCommitter(lambda: Refusing(diagnosed=False))
    committer.start()
    try:
        with pytest.raises(Unavailable):
            committer.submit_sync([op("poison")])
        assert committer.poisoned == 0
    finally:
        committer.close()


def test_a_lone_diagnosed_failure_is_not_storable():
    committer = GroupCommitter(lambda: Refusing(diagnosed=True))
    committer.start()
    try:
        with pytest.raises(NotStorable):
            committer.submit_sync([op("poison")])
        assert committer.poisoned == 1
    finally:
        committer.close()
