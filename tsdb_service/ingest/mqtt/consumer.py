"""The MQTT consumer: messages from a broker, stored once each, acknowledged after.

It runs beside the HTTP listener, in the same process and event loop, and
writes through the same write seam (``store.write``) and group commit.

**Threads.** paho-mqtt's network thread reads the socket, keeps the
connection alive and reconnects with backoff (1 s doubling to
``--mqtt-reconnect-max-s``); ``on_message`` hashes the message and hands it
to the event loop. While ``BUFFER_BYTES`` of messages wait to be stored it
stops reading (one message always fits), and the broker holds the rest:
MQTT 5's Receive Maximum (``--mqtt-inflight``) bounds how many are sent
before the first is acknowledged.

**Acknowledgement.** Manual: a QoS 1 message's PUBACK is sent once
``store.write`` returned (the write is durable: on DuckDB in the ingest log,
on PostgreSQL committed), and in the order the messages arrived, as MQTT
asks. A message received on a connection that has since dropped is not
acknowledged on the next one: the broker sends it again (with DUP set).

**Exactly once in the store.** Each QoS 1 message's identity (a
``write.ops.Delivery``: client id, a sequence number, the packet id and a
BLAKE2b-128 digest of topic and payload) is written in the same transaction
as its samples or its rejected row. A redelivery (DUP set) whose packet id
and digest are among this client id's last ``window`` deliveries was stored
before: it is acknowledged and not stored again. Only a message flagged DUP
is ever a candidate. Why that window suffices and where the guarantee ends:
docs/mqtt.md, "Delivery guarantees".

**A lost session is a fresh window.** Packet ids belong to a session: when
the broker answers a connection with session-present 0 (it restarted
without its state, the session expired, another client took our id), it
will redeliver nothing from before, and the packet ids it gives from now on
start again. So before subscribing on such a connection the window is
emptied, in memory and, durably, in the database (a marker delivery whose
``prune_below`` forgets every earlier one); only then is the subscription
sent, so no message of the new session can meet a delivery of the old one,
even across a crash. (Without a session the broker holds no subscription
for us either: nothing arrives before we subscribe.)

**Failures.** A message we cannot use is rejected: kept in the rejected
store with its topic, then acknowledged. A write that fails because the
database is unavailable (or its outcome is unknown) is retried with backoff
until it is stored, checking first whether its delivery landed; meanwhile
the message is not acknowledged and later ones wait behind it. A write the
database refuses for its content, every time (``NotStorable``, after the
group committer's bounded attempts), will never succeed: the message is
**poisoned**, kept in the rejected store like a rejected one (with the
database's reason) and acknowledged, so the messages behind it go on. So
is one whose write failed ``POISON_ATTEMPTS`` times, whatever the error,
while other messages were stored meanwhile.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import ssl
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import partial
from typing import Any, Protocol, TypeVar

import paho.mqtt.client as paho
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from tsdb_service.core.errors import NotStorable, TsdbError
from tsdb_service.ingest.mqtt.config import BUFFER_BYTES, MqttConfig
from tsdb_service.ingest.mqtt.messages import Message, parse_message, rejected
from tsdb_service.parse import ValuesLayout
from tsdb_service.write.ops import AppendSamples, Delivery, RecordDelivery, RecordRejected, WriteOp

log = logging.getLogger(__name__)

T = TypeVar("T")
KEEPALIVE_S = 30
RETRY_DELAY_S = 0.1
RETRY_MAX_DELAY_S = 5.0
STOP_TIMEOUT_S = 10.0
POISON_ATTEMPTS = 5  # failed writes of one message, while others are stored, before it is set aside
_PARSE_INLINE_MAX = 64 * 1024  # larger payloads are parsed in the threadpool, as over HTTP


class MqttStore(Protocol):
    """What the consumer needs of the store (``http.store.ServiceStore`` and one more)."""

    async def write(self, op: WriteOp) -> None: ...

    async def read(self, fn: Callable[[], T], *, memory_first: bool = True, consistent: bool = True) -> T: ...

    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None: ...

    def deliveries(self, client_id: str, limit: int) -> list[tuple[int, int, bytes]]: ...


def delivery_digest(topic: bytes, payload: bytes) -> bytes:
    return hashlib.blake2b(topic + b"\0" + payload, digest_size=16).digest()


class Window:
    """The last ``size`` deliveries' (packet id, digest), for membership."""

    def __init__(self, size: int):
        self._order: deque[tuple[int, bytes]] = deque()
        self._count: Counter[tuple[int, bytes]] = Counter()
        self.size = size

    def add(self, key: tuple[int, bytes]) -> None:
        self._order.append(key)
        self._count[key] += 1
        while len(self._order) > self.size:
            old = self._order.popleft()
            self._count[old] -= 1
            if not self._count[old]:
                del self._count[old]

    def __contains__(self, key: object) -> bool:
        return key in self._count


@dataclass(slots=True)
class _Item:
    """A message from arrival to acknowledgement."""

    message: Message
    size: int
    generation: int
    done: bool = False
    ack: bool = False  # acknowledge once done (stored, rejected or a known redelivery)


@dataclass(slots=True)
class _Session:
    """What belongs to one broker session: the deliveries that may come
    again (``window``), and the first deliveries being written (a
    redelivery waits for its first delivery's write)."""

    window: Window
    writing: dict[tuple[int, bytes], asyncio.Event] = field(default_factory=dict)


@dataclass(slots=True)
class MqttStats:
    """Counters for ``/metrics`` (``telemetry.MqttCollector``)."""

    received: int = 0
    stored: int = 0
    rejected: int = 0
    redelivered: int = 0
    poisoned: int = 0  # refused by the database for their content: kept in the rejected store
    write_retries: int = 0
    connects: int = 0
    sessions_lost: int = 0  # connections on which the broker had no session for us (a fresh window)
    acks_skipped: int = 0  # received on a connection that dropped before the ack: the broker resends


class MqttConsumer:
    def __init__(self, config: MqttConfig, store: MqttStore):
        self.config = config
        self.store = store
        self.stats = MqttStats()
        self._session = _Session(Window(config.window))
        self._next_seq = 1
        self._writes_ok = 0  # writes that went through (a message failing alone while it grows is poison)
        self._order: deque[_Item] = deque()
        self._tasks: set[asyncio.Task] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._client: paho.Client | None = None
        self._stopping = False
        # Shared with the network thread.
        self._ack_lock = threading.Lock()
        self._generation = 0  # grows with every connection made or lost
        self._connected = False
        self._room = threading.Condition()
        self._buffered = 0
        self._state_since = time.time()
        self._problem: str | None = "not connected yet"
        self.subscribed = threading.Event()  # set once the broker granted our subscriptions (the first time)
        self._warned_down = False

    # -- life -------------------------------------------------------------------------------

    async def start(self) -> None:
        """Remember what this client id stored before (after the store
        applied everything it acknowledged), then connect in the background:
        a broker that is away does not stop the service."""
        self._loop = asyncio.get_running_loop()
        cid, window = self.config.client_id, self.config.window
        recent = await self.store.read(lambda: self.store.deliveries(cid, window), memory_first=False)
        for _seq, packet_id, digest in reversed(recent):
            self._session.window.add((packet_id, digest))
        self._next_seq = (recent[0][0] + 1) if recent else 1
        self._client = self._make_client()
        self._client.connect_async(
            self.config.host, self.config.port, KEEPALIVE_S, clean_start=False, properties=self._connect_properties()
        )
        self._client.loop_start()
        log.info(
            "MQTT: consuming %s from %s as client %s (QoS %d)",
            ", ".join(self.config.filters),
            self.config.url,
            cid,
            self.config.qos,
        )

    async def stop(self, timeout: float = STOP_TIMEOUT_S) -> None:
        """Stop taking messages, finish storing (and acknowledge) those in
        hand for up to ``timeout`` seconds, then disconnect. What is left
        unacknowledged the broker sends again to the next start."""
        self._stopping = True
        with self._room:
            self._room.notify_all()
        if self._tasks:
            _, pending = await asyncio.wait(set(self._tasks), timeout=timeout)
            for task in pending:
                task.cancel()
            if pending:
                await asyncio.gather(*pending, return_exceptions=True)
        client = self._client
        if client is not None:
            with self._ack_lock:
                self._connected = False
                self._generation += 1
            await asyncio.to_thread(_disconnect, client)

    def _make_client(self) -> paho.Client:
        cfg = self.config
        client = paho.Client(
            paho.CallbackAPIVersion.VERSION2, client_id=cfg.client_id, protocol=paho.MQTTv5, manual_ack=True
        )
        if cfg.username:
            client.username_pw_set(cfg.username, cfg.password or None)
        if cfg.tls:
            context = ssl.create_default_context(cafile=cfg.ca_file or None)
            if cfg.cert_file:
                context.load_cert_chain(cfg.cert_file, cfg.key_file)
            client.tls_set_context(context)
        client.reconnect_delay_set(1, cfg.reconnect_max_s)
        client.on_connect = self._on_connect
        client.on_connect_fail = self._on_connect_fail
        client.on_disconnect = self._on_disconnect
        client.on_subscribe = self._on_subscribe
        client.on_message = self._on_message
        return client

    def _connect_properties(self) -> Properties:
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = self.config.session_expiry_s
        props.ReceiveMaximum = self.config.inflight
        props.MaximumPacketSize = self.config.max_packet_bytes
        return props

    # -- the network thread ---------------------------------------------------------------------

    def _on_connect(self, client, userdata, flags, reason_code, properties) -> None:
        if reason_code.is_failure:
            self._down(f"the broker refused the connection: {reason_code}")
            return
        with self._ack_lock:
            self._generation += 1
            self._connected = True
        self.stats.connects += 1
        self._state_since = time.time()
        self._problem = "connected, subscribing"
        self._warned_down = False
        session = "resumed our session" if flags.session_present else "started a new session"
        if not flags.session_present and self.stats.connects > 1:
            session += " (the broker had lost ours: what was published meanwhile was not kept for us)"
        log.info("MQTT: connected to %s as %s, %s", self.config.url, self.config.client_id, session)
        if self.stats.connects == 1:
            self._warn_guessable_id()
        if flags.session_present:
            self._subscribe(client)
            return
        loop, generation = self._loop, self._generation
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop has closed: we are stopping
                loop.call_soon_threadsafe(self._spawn, self._fresh_session(client, generation))

    def _subscribe(self, client: paho.Client) -> None:
        options = SubscribeOptions(qos=self.config.qos, retainHandling=SubscribeOptions.RETAIN_DO_NOT_SEND)
        client.subscribe([(topic_filter, options) for topic_filter in self.config.filters])

    def _warn_guessable_id(self) -> None:
        """The broker took us without credentials under the default client
        id: any client that connects as ``tsdb-service-HOSTNAME`` takes our
        session, and with it the messages queued for us."""
        cfg = self.config
        if cfg.client_id_is_default and not cfg.username and not cfg.cert_file:
            log.warning(
                "MQTT: the broker %s accepted us without credentials, under the default client id %s, which "
                "anyone can guess: a client connecting with it takes our session and the messages queued for "
                "it. Set TSDB_MQTT_CLIENT_ID to an id of your own and let the broker authenticate clients and "
                "restrict each client id to its owner (docs/mqtt.md, 'What the broker must enforce')",
                cfg.url,
                cfg.client_id,
            )

    def _on_subscribe(self, client, userdata, mid, reason_codes, properties) -> None:
        refused = [
            f"{topic_filter} ({code})"
            for topic_filter, code in zip(self.config.filters, reason_codes, strict=False)
            if code.is_failure
        ]
        if refused:
            self._problem = f"the broker refused the subscription to {', '.join(refused)}"
            log.error("MQTT: %s", self._problem)
            return
        self._problem = None
        self.subscribed.set()

    def _on_connect_fail(self, client, userdata) -> None:
        exc = sys.exc_info()[1]  # paho calls this inside its except clause
        self._down(f"cannot connect: {exc}" if exc is not None else "cannot connect")

    def _on_disconnect(self, client, userdata, flags, reason_code, properties) -> None:
        self._down(f"connection lost: {reason_code}" if not self._stopping else "disconnected")

    def _down(self, why: str) -> None:
        with self._ack_lock:
            was = self._connected
            self._generation += 1
            self._connected = False
        if was or self._problem is None or self._problem == "not connected yet":
            self._state_since = time.time()
        self._problem = why
        if self._stopping:
            return
        if was or not self._warned_down:
            log.warning("MQTT: %s at %s; retrying with backoff (HTTP ingest and reads go on)", why, self.config.url)
            self._warned_down = True

    def _on_message(self, client, userdata, msg: paho.MQTTMessage) -> None:
        if self._stopping:
            return  # not acknowledged: the broker sends it to our next start
        topic_bytes = msg._topic
        payload = bytes(msg.payload)
        size = len(topic_bytes) + len(payload)
        with self._room:
            while self._buffered and self._buffered + size > BUFFER_BYTES and not self._stopping:
                self._room.wait(0.5)  # stop reading: the broker and TCP hold the rest
            if self._stopping:
                return
            self._buffered += size
        message = Message(
            topic=topic_bytes.decode("utf-8", "replace"),
            payload=payload,
            qos=msg.qos,
            dup=bool(msg.dup),
            packet_id=msg.mid,
            digest=delivery_digest(topic_bytes, payload),
            properties=_properties(msg.properties),
            received_at=datetime.now(UTC),
        )
        generation = self._generation
        loop = self._loop
        if loop is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop has closed: we are stopping
            loop.call_soon_threadsafe(self._arrived, _Item(message, size, generation))

    # -- the event loop ---------------------------------------------------------------------------

    def _arrived(self, item: _Item) -> None:
        self.stats.received += 1
        self._order.append(item)
        self._spawn(self._process(item))

    def _spawn(self, work) -> None:
        task = asyncio.ensure_future(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _fresh_session(self, client: paho.Client, generation: int) -> None:
        """The broker has no session for us: forget every delivery of the
        old one (in memory now, in the database before subscribing), then
        subscribe, unless the connection dropped meanwhile (the next one
        decides again)."""
        self._session = _Session(Window(self.config.window))
        seq = self._next_seq
        self._next_seq += 1
        marker = Delivery(self.config.client_id, seq, 0, b"", datetime.now(UTC), prune_below=seq)
        try:
            if not await self._write(RecordDelivery(marker), marker, counted=False):
                return  # stopping
        except TsdbError as exc:  # refused for its content: cannot be (a marker is ids only); go on in memory
            log.error("MQTT: the earlier deliveries could not be forgotten in the database: %s", exc.description)
        self.stats.sessions_lost += 1
        with self._ack_lock:
            current = self._connected and generation == self._generation
        if current:
            self._subscribe(client)

    async def _process(self, item: _Item) -> None:
        try:
            item.ack = await self._handle(item.message)
        except asyncio.CancelledError:
            raise
        except Exception:  # a bug: the message stays unacknowledged, the broker resends it after a reconnect
            log.exception("MQTT: message on %r could not be handled", item.message.topic[:200])
        finally:
            item.done = True
            with self._room:
                self._buffered -= item.size
                self._room.notify_all()
            self._flush_acks()

    async def _handle(self, m: Message) -> bool:
        """Store (or reject) ``m`` unless it is a redelivery of one stored
        already; True once it may be acknowledged."""
        if m.qos == 0:
            op = await self._op(m, None)
            await self._store_or_set_aside(m, op, None)
            return False
        key = (m.packet_id, m.digest)
        session = self._session  # the broker's session this message belongs to
        if m.dup:  # only a redelivery can have been stored before
            pending = session.writing.get(key)
            if pending is not None:  # its first delivery is being written right now
                await pending.wait()
            if key in session.window:
                self.stats.redelivered += 1
                return True
        seq = self._next_seq
        self._next_seq += 1
        window = self.config.window
        prune = seq - window if seq % window == 0 else 0
        delivery = Delivery(self.config.client_id, seq, m.packet_id, m.digest, m.received_at, prune)
        written = session.writing[key] = asyncio.Event()
        try:
            op = await self._op(m, delivery)
            if not await self._store_or_set_aside(m, op, delivery):
                return False
        finally:
            written.set()
            if session.writing.get(key) is written:
                del session.writing[key]
        session.window.add(key)
        return True

    async def _store_or_set_aside(self, m: Message, op: WriteOp, delivery: Delivery | None) -> bool:
        """Write ``op``; when the database refuses it for its content, keep
        ``m`` in the rejected store instead. False when stopping first."""
        try:
            return await self._write(op, delivery)
        except TsdbError as exc:  # 4xx: NotStorable, it would fail however often it is tried
            if isinstance(op, RecordRejected):
                raise  # the rejected store takes anything (storage.rejected): a bug, logged by _process
            log.error("MQTT: a message on %r is set aside in the rejected store: %s", m.topic[:200], exc.description)
            aside = RecordRejected(rejected(m, exc, self.config), delivery)
            if not await self._write(aside, delivery, counted=False):
                return False
            self.stats.poisoned += 1
            return True

    async def _op(self, m: Message, delivery: Delivery | None) -> WriteOp:
        """The write ``m`` makes: its samples, or its rejection. A parse that
        needs the database (a ``values`` layout on PostgreSQL) and cannot
        have it is retried like a failed write."""
        delay = RETRY_DELAY_S
        while True:
            try:
                parse = partial(parse_message, m, self.config, self.store.values_layout)
                inline = len(m.payload) <= _PARSE_INLINE_MAX
                entities = await self.store.read(parse, memory_first=inline, consistent=False)
            except TsdbError as exc:
                if exc.status < 500:
                    return RecordRejected(rejected(m, exc, self.config), delivery)
                if self._stopping:
                    raise
                log.warning("MQTT: cannot parse a message on %r yet, retrying: %s", m.topic[:200], exc.description)
                await asyncio.sleep(delay)
                delay = min(delay * 2, RETRY_MAX_DELAY_S)
                continue
            return AppendSamples(entities, deliveries=() if delivery is None else (delivery,))

    async def _write(self, op: WriteOp, delivery: Delivery | None, counted: bool = True) -> bool:
        """Write ``op`` until it is stored; False when stopping first; a 4xx
        ``TsdbError`` (``NotStorable``) when the database refuses it for its
        content. ``counted``: count it as stored or rejected (``/metrics``)."""
        delay = RETRY_DELAY_S
        others_before, attempts = self._writes_ok, 0
        while True:
            try:
                await self.store.write(op)
                break
            except Exception as exc:
                if isinstance(exc, TsdbError) and exc.status < 500:
                    raise  # the database refuses it for its content: retrying cannot help
                self.stats.write_retries += 1
                attempts += 1
                if self._stopping:
                    return False
                reason = getattr(exc, "description", None) or str(exc) or type(exc).__name__
                log.warning("MQTT: storing a message failed, retrying in %.1f s: %s", delay, reason)
                await asyncio.sleep(delay)
                delay = min(delay * 2, RETRY_MAX_DELAY_S)
                if delivery is not None and await self._recorded(delivery.seq):
                    break  # a commit whose outcome was unknown did land
                if attempts >= POISON_ATTEMPTS and self._writes_ok > others_before:
                    # The store took other messages meanwhile: this one is the trouble.
                    raise NotStorable(
                        f"storing it failed {attempts} times while other messages were stored: {reason}"
                    ) from None
        self._writes_ok += 1
        if not counted:
            return True
        if isinstance(op, RecordRejected):
            self.stats.rejected += 1
        else:
            self.stats.stored += 1
        return True

    async def _recorded(self, seq: int) -> bool:
        cid, window = self.config.client_id, self.config.window
        try:
            recent = await self.store.read(lambda: self.store.deliveries(cid, window), memory_first=False)
        except Exception:
            return False
        return any(row[0] == seq for row in recent)

    def _flush_acks(self) -> None:
        """Acknowledge, in arrival order, every finished message at the head."""
        order = self._order
        while order and order[0].done:
            item = order.popleft()
            if item.ack:
                self._ack(item)

    def _ack(self, item: _Item) -> None:
        client = self._client
        with self._ack_lock:
            if client is not None and self._connected and item.generation == self._generation:
                client.ack(item.message.packet_id, item.message.qos)
                return
        self.stats.acks_skipped += 1

    # -- reports ------------------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._connected

    def health(self) -> str | None:
        """None while connected and subscribed; else a line for ``/health``."""
        problem = self._problem
        if problem is None:
            return None
        since = datetime.fromtimestamp(self._state_since, UTC).isoformat(timespec="seconds")
        return (
            f"MQTT {self.config.url} ({self.config.client_id}): {problem} (since {since}); HTTP ingest and reads work"
        )

    def snapshot(self) -> dict[str, Any]:
        """Numbers for ``/metrics``."""
        head = self._order[0].message.received_at if self._order else None
        lag = (datetime.now(UTC) - head).total_seconds() if head is not None else 0.0
        s = self.stats
        return {
            "connected": 1 if self._connected else 0,
            "received": s.received,
            "stored": s.stored,
            "rejected": s.rejected,
            "redelivered": s.redelivered,
            "poisoned": s.poisoned,
            "write_retries": s.write_retries,
            "connects": s.connects,
            "sessions_lost": s.sessions_lost,
            "inflight": len(self._order),
            "buffered_bytes": self._buffered,
            "oldest_unacked_s": lag,
        }


def _properties(props: Properties | None) -> tuple[tuple[str, str], ...]:
    """MQTT 5 user properties, and the Content Type property as a header."""
    if props is None:
        return ()
    out = [(str(k), str(v)) for k, v in getattr(props, "UserProperty", ()) or ()]
    content_type = getattr(props, "ContentType", None)
    if content_type:
        out.append(("Content-Type", str(content_type)))
    return tuple(out)


def _disconnect(client: paho.Client) -> None:
    """Send what is queued (the last acknowledgements), then DISCONNECT; stop the thread."""
    with contextlib.suppress(Exception):
        client.disconnect()
    client.loop_stop()
