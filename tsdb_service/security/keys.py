"""API keys: long random secrets with scopes and optional tenants.

Keys are kept only as SHA-256 digests (a key file holds nothing else), and a
presented key is compared against every digest with ``hmac.compare_digest``,
without stopping at a match, so the time taken says nothing about which key
came close. A plain hash suffices because keys are long random strings (at
least ``MIN_KEY_LENGTH`` characters), not passwords one could guess.
"""

from __future__ import annotations

import hashlib
import hmac
import re
from pathlib import Path

from tsdb_service.security.principals import Principal, parse_scopes, parse_tenants

MIN_KEY_LENGTH = 16
# RFC 6750 token68 characters: a key must travel as "Authorization: Bearer KEY".
_KEY = re.compile(r"^[A-Za-z0-9._~+/=-]+$")
_HEX_DIGEST = re.compile(r"^[0-9a-f]{64}$")


def digest(key: str) -> bytes:
    return hashlib.sha256(key.encode("utf-8")).digest()


class KeyRing:
    """The configured keys, as ``(digest, principal)`` pairs."""

    def __init__(self, entries: list[tuple[bytes, Principal]]):
        self._entries = entries

    def __len__(self) -> int:
        return len(self._entries)

    def lookup(self, presented: str) -> Principal | None:
        wanted = digest(presented)
        found = None
        for candidate, principal in self._entries:
            if hmac.compare_digest(candidate, wanted) and found is None:
                found = principal
        return found

    @classmethod
    def from_settings(cls, inline: str, file: str) -> KeyRing | None:
        entries = parse_inline(inline)
        if file:
            entries += parse_file(Path(file))
        return cls(entries) if entries else None


def parse_inline(raw: str) -> list[tuple[bytes, Principal]]:
    """``KEY:SCOPES[:TENANTS]`` entries separated by ``;`` or whitespace."""
    entries = []
    for n, entry in enumerate(re.split(r"[;\s]+", raw.strip()), start=1):
        if not entry:
            continue
        key, _, rest = entry.partition(":")
        where = f"TSDB_API_KEYS: entry {n}"
        if len(key) < MIN_KEY_LENGTH or not _KEY.match(key):
            raise ValueError(
                f"{where}: a key needs at least {MIN_KEY_LENGTH} characters from A-Z a-z 0-9 . _ ~ + / = -"
            )
        scopes, _, tenants = rest.partition(":")
        entries.append((digest(key), Principal(f"key{n}", parse_scopes(scopes, where), parse_tenants(tenants or None))))
    return entries


def parse_file(path: Path) -> list[tuple[bytes, Principal]]:
    """One ``SHA256HEX SCOPES [TENANTS] [# comment]`` per line; the digest
    of a key is ``printf %s KEY | sha256sum``."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ValueError(f"TSDB_API_KEYS_FILE: cannot read the API keys file {str(path)!r}: {exc.strerror}") from None
    entries = []
    for number, line in enumerate(lines, start=1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        where = f"{path.name} line {number}"
        if len(fields) not in (2, 3) or not _HEX_DIGEST.match(fields[0].lower()):
            raise ValueError(f"{where}: expected 'SHA256HEX SCOPES [TENANTS]' (64 hex digits first)")
        tenants = parse_tenants(fields[2]) if len(fields) == 3 else None
        principal = Principal(f"{path.name}:{number}", parse_scopes(fields[1], where), tenants)
        entries.append((bytes.fromhex(fields[0]), principal))
    return entries
