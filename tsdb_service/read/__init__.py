"""The read seam: what the history layer and the faces may ask of storage.

Modelled on Prometheus' ``storage/interface.go``: a few small protocols by
role, each method taking one frozen request (``read.requests``) and
returning plain immutable rows (the NamedTuples and tuples of
``core.query``):

* ``SeriesCatalogue`` (``read.catalogue``): which series exist;
* ``SampleReader`` (``read.samples``): samples, aggregates, latest values;
* ``LocationReader`` (``read.locations``): positions and extents;
* ``TemporalReader`` (``read.instances``): NGSI-LD attribute instances;
* ``BulkReader`` (``read.bulk``): exports, copies, counts;
* ``BucketReader`` (``read.buckets``): time buckets and state changes for
  every face that draws (long windows).

A layer names the roles it uses (``HistoryReads`` for the history layer,
``TemporalReads`` for the NGSI-LD API); each backend's querier implements
all of them (``Querier``), and ``read.memory.MemoryQuerier`` does too, in
memory, for tests of the layers above.

**Threads and lifetimes.** Every method is safe to call from any number of
threads at once. A method may query the database: call it from a worker
thread (``Reader.read`` arranges that), never on the event loop. Each call
is its own snapshot of committed data (a write acknowledged before the call
is in it, one committed meanwhile may or may not be). Returned lists and
rows belong to the caller, tied to no cursor or connection, valid forever,
never updated by later writes. An unreadable database raises
``core.errors.Unavailable`` (503).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, TypeVar

from tsdb_service.read.buckets import BucketReader
from tsdb_service.read.bulk import BulkReader
from tsdb_service.read.catalogue import SeriesCatalogue
from tsdb_service.read.instances import TemporalReader
from tsdb_service.read.locations import LocationReader
from tsdb_service.read.samples import SampleReader

T = TypeVar("T")


class HistoryReads(SeriesCatalogue, SampleReader, LocationReader, BucketReader, Protocol):
    """What the history layer (QuantumLeap API, Grafana, the explorer) reads."""


class TemporalReads(SeriesCatalogue, LocationReader, TemporalReader, Protocol):
    """What the NGSI-LD temporal API reads."""


class Querier(HistoryReads, TemporalReader, BulkReader, Protocol):
    """Every read: what a backend's querier implements."""


class Reader(Protocol):
    """How a route reads: the querier, and the one awaited way to run a read
    off the event loop (``read.off_loop``)."""

    def querier(self) -> Querier: ...

    async def read(self, fn: Callable[[], T], *, memory_first: bool = True, consistent: bool = True) -> T:
        """``fn()``, awaited: from memory on the loop when it can answer so,
        else in the threadpool (see ``read.off_loop``). ``memory_first=False``
        goes to the threadpool at once. ``consistent``: first wait until
        every write acknowledged before the call is readable."""
        ...
