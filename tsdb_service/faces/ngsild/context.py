"""JSON-LD @contexts for the NGSI-LD API: which context a request uses, and
term ↔ IRI through it.

* The NGSI-LD core context ships with the package
  (``ngsi-ld-core-context-v1.9.jsonld``, ETSI GS CIM 009 V1.9.1 annex B), so
  nothing needs the network; every known core-context URL resolves to it.
* Other contexts come from configured local files (``TSDB_NGSILD_CONTEXTS``,
  ``URL=path`` pairs) or are fetched over HTTP(S) by ``http.outbound``
  (public addresses only unless allowed, few redirects, a total deadline,
  bounded bytes after decompression; never with ``TSDB_LD_CONTEXT_OFFLINE``).
* A request's context is loaded in two steps. ``ContextStore.prepare``
  (async, on the event loop) checks what the request carries inline (size,
  absolute http(s) references) and loads every document it needs, following
  ``@context`` and ``@import`` references inside documents; a slow server
  costs a waiting coroutine, not a thread. ``Prepared.terms()`` (in the
  threadpool) then builds the ``TermMap`` with PyLD, and only when the
  context proved valid are the fetched documents and the term map cached.
* Caches are bounded by count and bytes (``TSDB_LD_CONTEXT_CACHE_BYTES``)
  and expire: a document is fresh for ``CACHE_SECONDS`` and kept as a
  fallback (a stale copy beats an error) for ``STALE_SECONDS``.
* Nothing cached is ever handed to PyLD: documents are kept as bytes and
  every PyLD call gets its own parsed copy (and its own PyLD context
  resolver), so one request's context (an ``@import`` that PyLD merges into
  the imported document, say) can never change what another request's
  context means.
* Expansion and compaction are PyLD's. A request pays JSON-LD processing
  only for terms its context has not seen yet: each ``TermMap`` (one per
  distinct context) caches its answers, up to ``ANSWER_BYTES``.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any
from urllib.parse import urljoin

import anyio
import orjson
from pyld import jsonld
from pyld.context_resolver import ContextResolver

from tsdb_service.core.config import url_prefixes
from tsdb_service.core.errors import BadRequestData, LdContextNotAvailable
from tsdb_service.http.outbound import FetchFailed, FetchPolicy, fetch

log = logging.getLogger(__name__)

CORE_CONTEXT_URL = "https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context-v1.9.jsonld"
CORE_CONTEXT_FILE = Path(__file__).with_name("ngsi-ld-core-context-v1.9.jsonld")
# Earlier core contexts: our v1.9 defines every term they define, the same way.
CORE_CONTEXT_URLS = frozenset(
    {CORE_CONTEXT_URL, "https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context.jsonld"}
    | {f"https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context-v1.{n}.jsonld" for n in range(3, 10)}
)
_CORE_BYTES = CORE_CONTEXT_FILE.read_bytes()
JSONLD_CONTEXT_REL = "http://www.w3.org/ns/json-ld#context"
DEFAULT_VOCAB = "https://uri.etsi.org/ngsi-ld/default-context/"
ACCEPT = "application/ld+json, application/json;q=0.9"
CACHE_SECONDS = 3600.0  # a fetched document is fresh this long
STALE_SECONDS = 86_400.0  # and kept this long, for when a refresh fails
CACHE_BYTES = 32 << 20  # default TSDB_LD_CONTEXT_CACHE_BYTES
INLINE_MAX_BYTES = 64 << 10  # default TSDB_LD_INLINE_CONTEXT_MAX_BYTES
MAX_CACHED_DOCUMENTS = 256
MAX_TERM_MAPS = 256
MAX_DOCUMENTS = 16  # context documents one request's context may need
MAX_CONTEXT_DEPTH = 16
ANSWER_BYTES = 256 << 10  # term answers one term map caches
_HTTP_URL = re.compile(r"^https?://", re.IGNORECASE)
_LINK = re.compile(r"<([^>]*)>\s*((?:;\s*[^;,]+)*)")


def core_context() -> dict:
    """The core context document (``{"@context": {...}}``), a fresh copy."""
    return orjson.loads(_CORE_BYTES)


def link_context(header: str | None) -> str | None:
    """The context URL of a ``Link`` header with the JSON-LD context
    relation, or None. Two such links are a 400 (the spec allows one)."""
    if not header:
        return None
    found = []
    for match in _LINK.finditer(header):
        url, params = match.group(1).strip(), match.group(2)
        rels = re.findall(r'rel\s*=\s*"?([^";]+)"?', params)
        if any(rel.strip() == JSONLD_CONTEXT_REL for rel in rels):
            found.append(url)
    if len(found) > 1:
        raise BadRequestData("a request may carry only one JSON-LD context Link header")
    if found and not re.match(r"^https?://", found[0]):
        raise BadRequestData(f"the JSON-LD context link must be an http(s) URL, not {found[0][:80]!r}")
    return found[0] if found else None


class ContextStore:
    """Loads context documents (core, local files, the network) and keeps
    the valid ones and the term maps built from them, bounded."""

    def __init__(
        self,
        local_files: Mapping[str, str] | None = None,
        *,
        policy: FetchPolicy | None = None,
        offline: bool = False,
        cache_bytes: int = CACHE_BYTES,
        inline_max_bytes: int = INLINE_MAX_BYTES,
    ):
        self._local = {url: Path(path) for url, path in (local_files or {}).items()}
        self.policy = policy or FetchPolicy(accept=ACCEPT)
        self.offline = offline
        self.cache_bytes = cache_bytes
        self.inline_max_bytes = inline_max_bytes
        self._documents: OrderedDict[str, _Cached] = OrderedDict()
        self._documents_bytes = 0
        self._maps: OrderedDict[bytes, tuple[float, TermMap]] = OrderedDict()
        self._maps_bytes = 0
        self._lock = threading.Lock()

    @classmethod
    def from_settings(cls, settings: Any) -> ContextStore:
        policy = FetchPolicy(
            deadline=settings.ngsild_context_timeout,
            max_bytes=settings.ld_context_max_bytes,
            allow=url_prefixes(settings.ld_context_allow),
            accept=ACCEPT,
        )
        return cls(
            parse_local_contexts(settings.ngsild_contexts),
            policy=policy,
            offline=settings.ld_context_offline,
            cache_bytes=settings.ld_context_cache_bytes,
            inline_max_bytes=settings.ld_inline_context_max_bytes,
        )

    # -- step 1, on the event loop: every document the context needs ---------------

    async def prepare(self, context: str | list | dict | None) -> Prepared:
        """The request's context checked and its documents loaded (see the
        module docstring); 400 for a context that cannot be valid, 503
        LdContextNotAvailable for one that cannot be loaded."""
        key = self._key(context)
        found = self._cached_map(key)
        if found is not None:
            return Prepared(self, context, key, terms=found)
        documents: dict[str, bytes] = {}
        fetched: dict[str, bytes] = {}
        pending = _references(context, None)
        deadline = time.monotonic() + self.policy.deadline
        while pending:
            url = pending.pop(0)
            if url in documents or url in CORE_CONTEXT_URLS:
                continue
            if len(documents) >= MAX_DOCUMENTS:
                raise BadRequestData(f"the @context needs more than {MAX_DOCUMENTS} context documents")
            raw, fresh = await self._document(url, deadline)
            documents[url] = raw
            if fresh:
                fetched[url] = raw
            pending += _references(_parse(raw, url).get("@context"), url)
        return Prepared(self, context, key, documents=documents, fetched=fetched)

    def term_map(self, context: str | list | dict | None) -> TermMap:
        """``prepare`` then ``terms``, for callers outside the event loop (tests, commands)."""
        return anyio.run(self.prepare, context).terms()

    def _key(self, context: str | list | dict | None) -> bytes:
        """The context's identity (its canonical JSON); an inline context
        larger than ``inline_max_bytes`` is a 400."""
        try:
            key = orjson.dumps(context, option=orjson.OPT_SORT_KEYS)
        except (TypeError, orjson.JSONEncodeError) as exc:  # nested too deep
            raise BadRequestData(f"the @context cannot be processed: {exc}") from None
        if not isinstance(context, str) and len(key) > self.inline_max_bytes:
            raise BadRequestData(
                f"the inline @context has {len(key)} bytes; at most {self.inline_max_bytes} are accepted "
                "(TSDB_LD_INLINE_CONTEXT_MAX_BYTES): name a context document by URL instead"
            )
        return key

    async def _document(self, url: str, deadline: float) -> tuple[bytes, bool]:
        """``(bytes, newly fetched)`` of a context document: a local file, a
        fresh cached copy, the network, or a stale copy when that fails."""
        if url in self._local:
            return self._read_local(url), False
        cached = self._cached_document(url)
        if cached is not None and cached.fresh:
            return cached.raw, False
        if self.offline:
            log.info("@context %s not loaded: remote contexts are off (TSDB_LD_CONTEXT_OFFLINE)", url[:200])
            raise LdContextNotAvailable(
                f"context could not be loaded: {url[:200]} (this service fetches no remote contexts)"
            )
        try:
            left = deadline - time.monotonic()
            if left <= 0:
                raise FetchFailed("the request's time for loading contexts is used up")
            raw = await fetch(url, replace(self.policy, deadline=min(left, self.policy.deadline)))
            _parse(raw, url)
        except FetchFailed as exc:
            log.info("@context %s could not be loaded: %s", url[:200], exc)
            if cached is not None:
                return cached.raw, False  # stale beats unavailable
            raise LdContextNotAvailable(f"context could not be loaded: {url[:200]}") from None
        return raw, True

    def _read_local(self, url: str) -> bytes:
        try:
            raw = self._local[url].read_bytes()
            _parse(raw, url)
        except (OSError, FetchFailed) as exc:
            log.warning("the configured context file for %s cannot be used: %s", url, exc)
            raise LdContextNotAvailable(f"context could not be loaded: {url[:200]}") from None
        return raw

    # -- the caches ------------------------------------------------------------------

    def _cached_document(self, url: str) -> _Cached | None:
        now = time.monotonic()
        with self._lock:
            found = self._documents.get(url)
            if found is None:
                return None
            if now - found.at >= STALE_SECONDS:
                self._drop_document(url)
                return None
            self._documents.move_to_end(url)
            return _Cached(found.raw, found.at, now - found.at < CACHE_SECONDS)

    def _drop_document(self, url: str) -> None:
        gone = self._documents.pop(url)
        self._documents_bytes -= len(gone.raw)

    def _remember(self, fetched: Mapping[str, bytes], key: bytes, terms: TermMap, remote: bool) -> None:
        """Keep valid documents and a built term map, within the bounds."""
        now = time.monotonic()
        with self._lock:
            for url, raw in fetched.items():
                if url in self._documents:
                    self._drop_document(url)
                self._documents[url] = _Cached(raw, now, True)
                self._documents_bytes += len(raw)
            if key in self._maps:
                self._maps_bytes -= self._maps.pop(key)[1].weight
            self._maps[key] = (now if remote else float("inf"), terms)
            self._maps_bytes += terms.weight
            # Least recently used out first: other term maps, then documents, then this map.
            while len(self._documents) > MAX_CACHED_DOCUMENTS:
                self._drop_document(next(iter(self._documents)))
            while len(self._maps) > MAX_TERM_MAPS:
                self._maps_bytes -= self._maps.popitem(last=False)[1][1].weight
            while self._maps and self.cached_bytes > self.cache_bytes:
                if len(self._maps) > 1 or not self._documents:
                    self._maps_bytes -= self._maps.popitem(last=False)[1][1].weight
                else:
                    self._drop_document(next(iter(self._documents)))

    def _cached_map(self, key: bytes) -> TermMap | None:
        """A term map for ``key`` built from documents that are still fresh."""
        with self._lock:
            found = self._maps.get(key)
            if found is None:
                return None
            built, terms = found
            if time.monotonic() - built >= CACHE_SECONDS:
                self._maps_bytes -= self._maps.pop(key)[1].weight
                return None
            self._maps.move_to_end(key)
            return terms

    @property
    def cached_bytes(self) -> int:
        """Bytes the caches hold: documents, and term maps with their context,
        documents and answers (a document shared by several counts for each)."""
        return self._documents_bytes + self._maps_bytes


@dataclass(frozen=True, slots=True)
class _Cached:
    raw: bytes
    at: float
    fresh: bool


class Prepared:
    """A request's context with every document it needs; ``terms()`` builds
    (or takes from the cache) its term map. Blocking: call it in the
    threadpool."""

    def __init__(
        self,
        store: ContextStore,
        context: Any,
        key: bytes,
        *,
        terms: TermMap | None = None,
        documents: Mapping[str, bytes] | None = None,
        fetched: Mapping[str, bytes] | None = None,
    ):
        self._store, self._context, self._key = store, context, key
        self._terms, self._documents, self._fetched = terms, documents or {}, fetched or {}

    def terms(self) -> TermMap:
        if self._terms is None:
            made = TermMap(self._context, self._documents, len(self._key))
            made.check()  # a context PyLD refuses is a 400, and nothing of it is cached
            remote = any(url not in self._store._local for url in self._documents)
            self._store._remember(self._fetched, self._key, made, remote)
            self._terms = made
        return self._terms


def _parse(raw: bytes, url: str) -> dict:
    """A context document: a JSON object with an ``@context``."""
    try:
        document = orjson.loads(raw)
    except orjson.JSONDecodeError:
        raise FetchFailed(f"{url[:200]!r} is not JSON") from None
    if not isinstance(document, dict) or "@context" not in document:
        raise FetchFailed(f"{url[:200]!r} is not a JSON-LD context document (no top-level @context)")
    return document


def _references(context: Any, base: str | None) -> list[str]:
    """Every context document ``context`` (the value of an ``@context``)
    refers to: strings in it, ``@import`` values and the scoped contexts of
    its term definitions. Relative references resolve against the document
    they are in (``base``); a request's own context has no base, so there
    they are a 400, like any reference that is not http(s)."""
    out: list[str] = []

    def visit(value: Any, depth: int) -> None:
        if depth > MAX_CONTEXT_DEPTH:
            raise BadRequestData(f"the @context nests scoped contexts more than {MAX_CONTEXT_DEPTH} deep")
        if isinstance(value, str):
            out.append(_absolute(value, base))
        elif isinstance(value, list):
            for item in value:
                visit(item, depth + 1)
        elif isinstance(value, dict):
            if isinstance(value.get("@import"), str):
                out.append(_absolute(value["@import"], base))
            for definition in value.values():
                if isinstance(definition, dict) and "@context" in definition:
                    visit(definition["@context"], depth + 1)

    visit(context, 0)
    return out


def _absolute(reference: str, base: str | None) -> str:
    url = reference if base is None else urljoin(base, reference)
    if not _HTTP_URL.match(url):
        if base is None:
            raise BadRequestData(
                f"the @context reference {reference[:80]!r} is not an absolute http(s) URL "
                "(a request's context has no base URL to resolve it against)"
            )
        raise LdContextNotAvailable(f"context could not be loaded: {reference[:200]} (not an http(s) URL)")
    return url


_failure = threading.local()  # the last LdContextNotAvailable of a thread's PyLD call


class TermMap:
    """Term ↔ IRI for one context, answers cached (up to ``ANSWER_BYTES``).

    It owns its context (as JSON) and documents (as bytes): each PyLD call
    gets fresh copies and a context resolver of its own, so nothing PyLD
    does to them outlives the call."""

    def __init__(self, context: str | list | dict | None, documents: Mapping[str, bytes] | None = None, size: int = 0):
        user = [] if context is None else (context if isinstance(context, list) else [context])
        user = [c for c in user if not (isinstance(c, str) and c in CORE_CONTEXT_URLS)]
        self.user_context: list = user
        self._context_json = orjson.dumps([*user, CORE_CONTEXT_URL])
        self._documents = dict(documents or {})
        self.weight = size + sum(len(raw) for raw in self._documents.values()) + ANSWER_BYTES
        self._expanded: dict[str, str] = {}
        self._compacted: dict[str, str] = {}
        self._answer_bytes = 0
        self._lock = threading.Lock()

    @property
    def context(self) -> list:
        """The context PyLD processes (a fresh copy): the user's, then the core context."""
        return orjson.loads(self._context_json)

    @property
    def response_context(self) -> str | list:
        """What a response's ``@context`` (or Link) names."""
        context = self.context
        return context[0] if len(context) == 1 else context

    @property
    def link_url(self) -> str:
        """The one context URL a ``Link`` header can carry."""
        first = self.user_context[0] if self.user_context else CORE_CONTEXT_URL
        return first if isinstance(first, str) else CORE_CONTEXT_URL

    def _loader(self, url: str, options: Any = None) -> dict:
        """PyLD's document loader: only this map's documents, each call a
        fresh copy. PyLD wraps what a loader raises in its own errors, so
        the real failure is also kept per thread."""
        raw = _CORE_BYTES if url in CORE_CONTEXT_URLS else self._documents.get(url)
        if raw is None:
            _failure.error = LdContextNotAvailable(f"context could not be loaded: {url[:200]}")
            raise _failure.error
        return {
            "contentType": "application/ld+json",
            "contextUrl": None,
            "documentUrl": url,
            "document": orjson.loads(raw),
        }

    def _options(self) -> dict:
        return {"documentLoader": self._loader, "contextResolver": ContextResolver({}, self._loader)}

    def check(self) -> None:
        """Process the context once, so a broken one fails the request
        early with a clear error."""
        self.expand_all(["type"])

    def expand(self, term: str) -> str:
        return self.expand_all([term])[0]

    def compact(self, iri: str) -> str:
        return self.compact_all([iri])[0]

    def expand_all(self, terms: Iterable[str]) -> list[str]:
        """Vocabulary-relative IRI expansion (attribute names, types)."""
        terms = list(terms)
        known = self._expanded
        missing = [t for t in dict.fromkeys(terms) if t not in known]
        if not missing:
            return [known[t] for t in terms]
        # @type values expand exactly like attribute names (vocab-relative)
        # and keep their order, so one PyLD call answers every new term.
        out = self._run(lambda: jsonld.expand({"@context": self.context, "@type": missing}, self._options()))
        got = out[0].get("@type", []) if out else []
        if len(got) != len(missing):
            got = [self._run(lambda t=t: _expand_one(self.context, t, self._options())) for t in missing]
        answers = dict(zip(missing, got, strict=True))
        self._keep(self._expanded, answers)
        return [known[t] if t in known else answers[t] for t in terms]

    def compact_all(self, iris: Iterable[str]) -> list[str]:
        iris = list(iris)
        answers: dict[str, str] = {}
        for iri in dict.fromkeys(iris):
            if iri in self._compacted:
                continue
            out = self._run(lambda iri=iri: jsonld.compact({"@type": [iri]}, self.context, self._options()))
            value = out.get("type", out.get("@type", iri))
            if isinstance(value, list):
                value = value[0] if value else iri
            answers[iri] = value
        self._keep(self._compacted, answers)
        return [self._compacted[i] if i in self._compacted else answers[i] for i in iris]

    def _keep(self, cache: dict[str, str], answers: Mapping[str, str]) -> None:
        """Cache answers while the map's answers stay within ``ANSWER_BYTES``."""
        with self._lock:
            for term, iri in answers.items():
                size = len(term) + len(iri) + 100
                if self._answer_bytes + size > ANSWER_BYTES:
                    return
                cache[term] = iri
                self._answer_bytes += size

    def _run(self, call):
        _failure.error = None
        try:
            return call()
        except LdContextNotAvailable:
            raise
        except jsonld.JsonLdError as exc:
            failed = getattr(_failure, "error", None)
            if failed is not None:
                raise failed from None
            raise BadRequestData(f"the JSON-LD @context cannot be processed: {_describe(exc)}") from None
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:  # PyLD on odd input
            raise BadRequestData(f"the JSON-LD @context cannot be processed: {str(exc)[:200]}") from None


def _expand_one(context: list, term: str, options: dict) -> str:
    out = jsonld.expand({"@context": context, "@type": term}, options)
    got = out[0].get("@type", [term]) if out else [term]
    return got[0] if got else term


def _describe(exc: Exception) -> str:
    parts: list[str] = []
    cause: BaseException | None = exc
    while cause is not None and len(parts) < 4:
        code = getattr(cause, "code", None)
        parts.append(f"{cause.args[0] if cause.args else cause}" + (f" ({code})" if code else ""))
        cause = getattr(cause, "cause", None)
    return "; ".join(str(p)[:200] for p in parts)


def parse_local_contexts(spec: str) -> dict[str, str]:
    """``TSDB_NGSILD_CONTEXTS``: ``URL=path`` pairs separated by ``;`` or
    white space."""
    out = {}
    for item in re.split(r"[;\s]+", spec.strip()):
        if not item:
            continue
        url, sep, path = item.rpartition("=")
        if not sep or not url or not path:
            raise ValueError(f"TSDB_NGSILD_CONTEXTS: entries are URL=path, not {item!r}")
        out[url] = path
    return out


def check_local_contexts(spec: str) -> dict[str, str]:
    """``parse_local_contexts``, and each entry usable: an http(s) URL (the
    ones a request's ``Link`` header names) and a readable JSON file.
    ``ValueError`` naming the entry; ``serve`` checks this at start, so a
    mistyped setting is not found at the first NGSI-LD request."""
    local = parse_local_contexts(spec)
    for url, path in local.items():
        if not re.match(r"^https?://[^/\s]+", url):
            raise ValueError(f"TSDB_NGSILD_CONTEXTS: {url!r} is not an http(s) URL (entries are URL=path)")
        try:
            orjson.loads(Path(path).read_text(encoding="utf-8"))
        except OSError as exc:
            raise ValueError(f"TSDB_NGSILD_CONTEXTS: cannot read {path} for {url}: {exc.strerror}") from None
        except ValueError as exc:
            raise ValueError(f"TSDB_NGSILD_CONTEXTS: {path} (for {url}) is not JSON: {exc}") from None
    return local
