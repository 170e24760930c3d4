"""The pieces of ``--ingest-processes`` below the servers (``ingest.relay``,
``http.handoff``, ``http.server.CoalescingTransport``): what a frame may be,
what a request's first bytes say, and writes leaving once per turn."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime

import pytest

from tsdb_service.core.errors import NotStorable
from tsdb_service.core.model import AttrSample, EntitySample, Kind, RejectedNotification
from tsdb_service.http.handoff import request_path
from tsdb_service.http.server import CoalescingTransport
from tsdb_service.ingest.relay import RelayClient, RelayServer
from tsdb_service.parse import ValuesLayout
from tsdb_service.write.ops import AppendSamples, RecordRejected


@pytest.mark.parametrize(
    ("head", "path"),
    [
        (b"GET /v2/entities?lastN=1 HTTP/1.1\r\n", b"/v2/entities"),
        (b"POST /v2/notify HTTP/1.1\r\nHost: x\r\n\r\n{}", b"/v2/notify"),
        (b"POST /v2/no", None),  # the target may go on
        (b"GET", None),
        (b"", None),
    ],
)
def test_a_request_path_is_read_only_once_the_target_is_complete(head, path):
    assert request_path(head) == path


class _Recorder:
    def __init__(self):
        self.writes: list[bytes] = []
        self.closed = self.aborted = False

    def write(self, data: bytes) -> None:
        self.writes.append(data)

    def is_closing(self) -> bool:
        return self.closed or self.aborted

    def close(self) -> None:
        self.closed = True

    def abort(self) -> None:
        self.aborted = True

    def get_write_buffer_size(self) -> int:
        return 0

    def get_extra_info(self, name: str):
        return f"extra {name}"


def test_the_writes_of_one_turn_leave_as_one_and_close_sends_what_is_pending():
    async def scenario():
        loop = asyncio.get_running_loop()
        raw = _Recorder()
        transport = CoalescingTransport(raw, loop)
        transport.write(b"HTTP/1.1 200 OK\r\n\r\n")
        transport.write(b"body")
        assert raw.writes == [] and transport.get_write_buffer_size() == 23
        await asyncio.sleep(0)
        assert raw.writes == [b"HTTP/1.1 200 OK\r\n\r\nbody"]
        transport.write(b"last")
        transport.close()
        assert raw.writes[-1] == b"last" and raw.closed
        assert transport.get_extra_info("peername") == "extra peername"

        dropped = _Recorder()
        transport = CoalescingTransport(dropped, loop)
        transport.write(b"never")
        transport.abort()
        await asyncio.sleep(0)
        assert dropped.writes == [] and dropped.aborted

    asyncio.run(scenario())


def _entity() -> EntitySample:
    stamp = datetime(2024, 5, 1, tzinfo=UTC)
    return EntitySample("t", "/", "urn:x", "T", stamp, [AttrSample("level", "Number", Kind.NUMBER, num=1.5)])


def test_writes_refusals_and_layouts_cross_the_relay_as_they_are(tmp_path):
    async def scenario():
        written: list = []

        async def write(op) -> None:
            if isinstance(op, AppendSamples) and op.entities[0].entity_id == "urn:refused":
                raise NotStorable("the database refused it")
            written.append(op)

        async def layout(tenant: str, subscription: str):
            return ValuesLayout(("id", "level"), None, "T") if subscription == "known" else None

        server = RelayServer(write, layout, max_frame=1 << 20)
        path = str(tmp_path / "relay.sock")
        await server.start(path)
        client = RelayClient()
        await client.connect(path)
        try:
            await asyncio.gather(*(client.write(AppendSamples([_entity()])) for _ in range(50)))
            refused = _entity()
            refused.entity_id = "urn:refused"
            with pytest.raises(Exception) as caught:
                await client.write(AppendSamples([refused]))
            assert (caught.value.status, caught.value.error) == (422, "NotStorable")
            rejected = RejectedNotification(
                "t", datetime(2024, 5, 1, tzinfo=UTC), "ParseError", "bad", "{}", b"\x00\xff"
            )
            await client.write(RecordRejected(rejected))
            assert await client.values_layout("t", "known") == ValuesLayout(("id", "level"), None, "T")
            assert await client.values_layout("t", "unknown") is None
        finally:
            client.close()
            await server.close()
        appended = [op for op in written if isinstance(op, AppendSamples)]
        assert len(appended) == 50 and appended[0].entities[0].attrs[0].num == 1.5
        assert appended[0].entities[0].time_index == datetime(2024, 5, 1, tzinfo=UTC)
        assert [op.rejected for op in written if isinstance(op, RecordRejected)] == [rejected]
        assert server.relayed == 51

    asyncio.run(scenario())


def test_a_frame_over_the_bound_closes_its_connection_and_fails_what_waits_on_it(tmp_path):
    async def scenario():
        async def write(op) -> None:
            pass

        async def layout(tenant: str, subscription: str):
            return None

        server = RelayServer(write, layout, max_frame=1024)
        path = str(tmp_path / "relay.sock")
        await server.start(path)
        client = RelayClient()
        await client.connect(path)
        try:
            big = _entity()
            big.attrs[0] = AttrSample("level", "Text", Kind.TEXT, txt="x" * 4096)
            with pytest.raises(Exception) as caught:
                await client.write(AppendSamples([big]))
            assert caught.value.status == 503
            await asyncio.wait_for(client.lost.wait(), 5)
        finally:
            client.close()
            await server.close()

    asyncio.run(scenario())
