"""Names: the one rule per kind, for ingest and for every query parser.

Attribute names, entity ids, entity types and service paths each have one
rule here, applied by the notification parser and by every endpoint that
takes them (history paths and parameters, ``op/query``, Grafana, deletes).

"Store what you accept, accept what you can serve": an attribute name the
ingest stores must be one every endpoint can be asked for, so the same rule
runs on both sides. A name is 1 to 256 characters (Orion's limit) without

* Orion's forbidden characters ``< > " ' = ;`` and ``( )``: Orion refuses
  them, and ``(`` opens a value path (``odom(twist.linear.x)``);
* ``,``: it separates the names of an ``attrs=`` list;
* white space (anywhere: leading and trailing white space would be lost
  from ``attrs=`` items, and Orion refuses it too) and control characters.

* ``.`` and ``..`` as the whole name: as a URL path segment
  (``/attrs/{name}``) clients resolve them as relative references.

Everything else is kept: unicode letters, and NGSI-LD names that are IRIs
(``https://example.org/ns#speed``, ``ex:speed``, ``https://x.org/a/b``);
``/`` is reached as ``%2F`` in a path segment (see ``tsdb_service.http.rawpath``).

Entity ids and types (``id_problem``) are NGSI-LD URIs as often as NGSIv2
words, so they keep more: 1 to 1024 characters without control characters,
``,`` (it separates ``id=`` and ``type=`` lists) or white space at either end
(list items are trimmed), and not ``.`` or ``..``.

Service paths (``service_path_problem``): ``/`` or ``/`` followed by
components of 1 to 256 characters separated by ``/``, without white space,
control characters, ``#`` (``/#`` selects a subtree in queries) or ``,``
(it separates the paths of one header).
"""

from __future__ import annotations

import re

MAX_NAME_CHARS = 256
FORBIDDEN = "<>\"'=;(),"
RULE = (
    f"attribute names are 1 to {MAX_NAME_CHARS} characters, without white space, "
    "control characters or any of the characters <>\"'=;(),"
)

_BAD = re.compile(r"[\s<>\"'=;(),\x00-\x1f\x7f-\x9f]")
_DOTS = frozenset({".", ".."})

MAX_ID_CHARS = 1024
ID_RULE = (
    f"entity ids and types are 1 to {MAX_ID_CHARS} characters, without control characters, ',' "
    "or white space at either end, and not '.' or '..'"
)
_ID_BAD = re.compile(r"[,\x00-\x1f\x7f-\x9f]")

MAX_COMPONENT_CHARS = 256
SERVICE_PATH_RULE = (
    f"a service path is '/' or '/'-separated components of 1 to {MAX_COMPONENT_CHARS} characters, "
    "without white space, control characters, '#' or ','"
)
_COMPONENT = re.compile(rf"[^/#,\s\x00-\x1f\x7f-\x9f]{{1,{MAX_COMPONENT_CHARS}}}\Z")

# Names already found valid: a notification repeats the same few names, so
# the hot path pays a set lookup instead of a regex scan. Bounded: a sender
# inventing names cannot make it grow without limit.
_VALID: set[str] = set()
_VALID_MAX = 65_536


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot be an attribute name, or None when it can."""
    if name in _VALID:
        return None
    if not name:
        return "is empty"
    if len(name) > MAX_NAME_CHARS:
        return f"is {len(name)} characters long (at most {MAX_NAME_CHARS})"
    bad = _BAD.search(name)
    if bad is not None:
        return f"contains {_describe(bad.group())}"
    if name in _DOTS:
        return "is a relative URL path segment"
    if len(_VALID) >= _VALID_MAX:
        _VALID.clear()
    _VALID.add(name)
    return None


def id_problem(value: str) -> str | None:
    """Why ``value`` cannot be an entity id or type, or None when it can."""
    if not value:
        return "is empty"
    if len(value) > MAX_ID_CHARS:
        return f"is {len(value)} characters long (at most {MAX_ID_CHARS})"
    bad = _ID_BAD.search(value)
    if bad is not None:
        return f"contains {_describe(bad.group())}"
    if value[0].isspace() or value[-1].isspace():
        return "starts or ends with white space"
    if value in _DOTS:
        return "is a relative URL path segment"
    return None


def normalize_service_path(path: str) -> str:
    """One trailing ``/`` after a component dropped (``/a/`` is ``/a``; ``//``
    and ``/a//`` keep their empty component), the same at ingest and in queries."""
    if len(path) > 2 and path[-1] == "/" and path[-2] != "/":
        return path[:-1]
    return path


def service_path_problem(path: str) -> str | None:
    """Why ``path`` (one absolute path, no trailing ``/``, no ``/#``) cannot
    be a service path, or None when it can."""
    if not path.startswith("/"):
        return "each path must start with '/'"
    if path == "/":
        return None
    for component in path[1:].split("/"):
        if not _COMPONENT.match(component):
            return _component_problem(component)
    return None


def _component_problem(component: str) -> str:
    if not component:
        return "has an empty component"
    if len(component) > MAX_COMPONENT_CHARS:
        return f"has a component of {len(component)} characters (at most {MAX_COMPONENT_CHARS})"
    bad = next(c for c in component if c in "#," or c.isspace() or _ID_BAD.match(c))
    return f"contains {_describe(bad)}"


def _describe(char: str) -> str:
    if char.isspace():
        return f"white space ({char!r})"
    if char in FORBIDDEN or char == "#":
        return repr(char)
    return f"the control character U+{ord(char):04X}"
