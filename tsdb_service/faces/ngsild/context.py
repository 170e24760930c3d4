"""JSON-LD @contexts for the NGSI-LD API: which context a request uses, and
term ↔ IRI through it.

* The NGSI-LD core context ships with the package
  (``ngsi-ld-core-context-v1.9.jsonld``, ETSI GS CIM 009 V1.9.1 annex B), so
  nothing needs the network; every known core-context URL resolves to it.
* Other contexts come from configured local files (``TSDB_NGSILD_CONTEXTS``,
  ``URL=path`` pairs) or are fetched over HTTP(S) with a short timeout and
  kept for ``CACHE_SECONDS`` (a stale copy is used when a refresh fails).
* Expansion and compaction are PyLD's. A request pays JSON-LD processing
  only for terms its context has not seen yet: each ``TermMap`` (one per
  distinct context list) caches its answers, and term maps are cached too.

Callers run in the threadpool: a first use may fetch a context.
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import httpx
from pyld import jsonld

from tsdb_service.core.errors import BadRequestData, LdContextNotAvailable

CORE_CONTEXT_URL = "https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context-v1.9.jsonld"
CORE_CONTEXT_FILE = Path(__file__).with_name("ngsi-ld-core-context-v1.9.jsonld")
# Earlier core contexts: our v1.9 defines every term they define, the same way.
CORE_CONTEXT_URLS = frozenset(
    {CORE_CONTEXT_URL, "https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context.jsonld"}
    | {f"https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context-v1.{n}.jsonld" for n in range(3, 10)}
)
JSONLD_CONTEXT_REL = "http://www.w3.org/ns/json-ld#context"
DEFAULT_VOCAB = "https://uri.etsi.org/ngsi-ld/default-context/"
CACHE_SECONDS = 3600.0
MAX_CONTEXT_BYTES = 1 << 20
MAX_TERM_MAPS = 256
_LINK = re.compile(r"<([^>]*)>\s*((?:;\s*[^;,]+)*)")


@lru_cache(maxsize=1)
def core_context() -> dict:
    """The core context document (``{"@context": {...}}``)."""
    return json.loads(CORE_CONTEXT_FILE.read_text(encoding="utf-8"))


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
    """Resolves context URLs to documents: core, local files, then HTTP."""

    def __init__(self, local_files: Mapping[str, str] | None = None, timeout: float = 2.0):
        self._local = {url: Path(path) for url, path in (local_files or {}).items()}
        self._timeout = timeout
        self._cache: dict[str, tuple[float, Any]] = {}
        self._lock = threading.Lock()
        self._maps: OrderedDict[tuple, TermMap] = OrderedDict()
        self.failure = threading.local()  # the last LdContextNotAvailable of a thread's PyLD call

    def document(self, url: str) -> Any:
        """The JSON document at ``url`` (a context), or LdContextNotAvailable."""
        if url in CORE_CONTEXT_URLS:
            return core_context()
        if url in self._local:
            return self._read_local(url)
        now = time.monotonic()
        cached = self._cache.get(url)
        if cached is not None and now - cached[0] < CACHE_SECONDS:
            return cached[1]
        try:
            doc = self._fetch(url)
        except LdContextNotAvailable:
            if cached is not None:
                return cached[1]  # stale beats unavailable
            raise
        with self._lock:
            self._cache[url] = (now, doc)
        return doc

    def _read_local(self, url: str) -> Any:
        try:
            return json.loads(self._local[url].read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise LdContextNotAvailable(f"the configured context file for {url} cannot be read: {exc}") from None

    def _fetch(self, url: str) -> Any:
        if not re.match(r"^https?://", url):
            raise LdContextNotAvailable(f"cannot load the @context {url[:80]!r}: only http(s) URLs are fetched")
        try:
            with httpx.Client(timeout=self._timeout, follow_redirects=True) as client:
                response = client.get(url, headers={"Accept": "application/ld+json, application/json"})
        except httpx.HTTPError as exc:
            raise LdContextNotAvailable(f"the @context {url} is not reachable: {type(exc).__name__}") from None
        if response.status_code != 200:
            raise LdContextNotAvailable(f"the @context {url} answered HTTP {response.status_code}")
        if len(response.content) > MAX_CONTEXT_BYTES:
            raise LdContextNotAvailable(f"the @context {url} is larger than {MAX_CONTEXT_BYTES} bytes")
        try:
            return response.json()
        except ValueError:
            raise LdContextNotAvailable(f"the @context {url} is not JSON") from None

    def loader(self, url: str, options: Any = None) -> dict:
        """PyLD's document loader interface. PyLD wraps what a loader raises
        in its own errors, so the real failure is also kept per thread."""
        try:
            document = self.document(url)
        except LdContextNotAvailable as exc:
            self.failure.error = exc
            raise
        return {"contentType": "application/ld+json", "contextUrl": None, "documentUrl": url, "document": document}

    def term_map(self, context: str | list | dict | None) -> TermMap:
        """The (cached) term map of a request's context: a URL, an inline
        context or a list of them; the core context always comes last."""
        key = _freeze(context)
        with self._lock:
            found = self._maps.get(key)
            if found is not None:
                self._maps.move_to_end(key)
                return found
        made = TermMap(self, context)
        made.check()
        with self._lock:
            self._maps[key] = made
            while len(self._maps) > MAX_TERM_MAPS:
                self._maps.popitem(last=False)
        return made


def _freeze(value: Any) -> Any:
    if isinstance(value, dict):
        return tuple(sorted((k, _freeze(v)) for k, v in value.items()))
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    return value


class TermMap:
    """Term ↔ IRI for one context, answers cached."""

    def __init__(self, store: ContextStore, context: str | list | dict | None):
        self._store = store
        user = [] if context is None else (context if isinstance(context, list) else [context])
        user = [c for c in user if not (isinstance(c, str) and c in CORE_CONTEXT_URLS)]
        self.user_context: list = user
        self.context: list = [*user, CORE_CONTEXT_URL]
        self._expanded: dict[str, str] = {}
        self._compacted: dict[str, str] = {}
        self._lock = threading.Lock()

    @property
    def response_context(self) -> str | list:
        """What a response's ``@context`` (or Link) names."""
        return self.context[0] if len(self.context) == 1 else list(self.context)

    @property
    def link_url(self) -> str:
        """The one context URL a ``Link`` header can carry."""
        first = self.user_context[0] if self.user_context else CORE_CONTEXT_URL
        return first if isinstance(first, str) else CORE_CONTEXT_URL

    def _options(self) -> dict:
        return {"documentLoader": self._store.loader}

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
        missing = [t for t in dict.fromkeys(terms) if t not in self._expanded]
        if missing:
            # @type values expand exactly like attribute names (vocab-relative)
            # and keep their order, so one PyLD call answers every new term.
            out = self._run(lambda: jsonld.expand({"@context": self.context, "@type": missing}, self._options()))
            got = out[0].get("@type", []) if out else []
            if len(got) != len(missing):
                got = [self._run(lambda t=t: _expand_one(self.context, t, self._options())) for t in missing]
            with self._lock:
                self._expanded.update(zip(missing, got, strict=True))
        return [self._expanded[t] for t in terms]

    def compact_all(self, iris: Iterable[str]) -> list[str]:
        iris = list(iris)
        missing = [i for i in dict.fromkeys(iris) if i not in self._compacted]
        for iri in missing:
            out = self._run(lambda iri=iri: jsonld.compact({"@type": [iri]}, self.context, self._options()))
            value = out.get("type", out.get("@type", iri))
            if isinstance(value, list):
                value = value[0] if value else iri
            with self._lock:
                self._compacted[iri] = value
        return [self._compacted[i] for i in iris]

    def _run(self, call):
        self._store.failure.error = None
        try:
            return call()
        except LdContextNotAvailable:
            raise
        except jsonld.JsonLdError as exc:
            failed = self._store.failure.error
            if failed is not None:
                raise failed from None
            raise BadRequestData(f"the JSON-LD @context cannot be processed: {_describe(exc)}") from None


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
            json.loads(Path(path).read_text(encoding="utf-8"))
        except OSError as exc:
            raise ValueError(f"TSDB_NGSILD_CONTEXTS: cannot read {path} for {url}: {exc.strerror}") from None
        except ValueError as exc:
            raise ValueError(f"TSDB_NGSILD_CONTEXTS: {path} (for {url}) is not JSON: {exc}") from None
    return local
