"""The steps of a value path, and following them into a value.

A value path names a place inside a structured value: ``odom(twist.twist.linear.x)``
is the attribute ``odom`` and the steps ``("twist", "twist", "linear",
"x")``. Steps are object keys separated by ``.`` and array indices ``[n]``
(0-based), which may follow a key (``covariance[0]``) or start the path
(``[0].range``). Keys may use any character except ``. , [ ] ( ) < > " ' = ;``
and white space.

One grammar for every place a path is written: history queries
(``history.valuepath``, which adds the attribute naming rule), the time
index's stamp paths (``core.timepaths``, the ``Fiware-TimeIndex-Attribute``
header) and the field maps of ``tsdb-service import rosbag``. Problems are
``ValueError`` with one line naming the path.
"""

from __future__ import annotations

import re

Steps = tuple[str | int, ...]

_KEY = r"""[^\s.,\[\]()<>"'=;]+"""
_STEP = re.compile(rf"\.?({_KEY})|\[(\d{{1,9}})\]")
MAX_STEPS = 32


def parse_steps(path: str, text: str | None = None) -> Steps:
    """``"twist.linear.x"`` → ``("twist", "linear", "x")``; ``text`` is what
    error messages quote (the whole value path, when the steps are part of one)."""
    shown = (text if text is not None else path)[:80]
    steps: list[str | int] = []
    pos = 0
    while pos < len(path):
        match = _STEP.match(path, pos)
        # A leading "." or a "." right after nothing is not allowed.
        if match is None or (pos == 0 and path[0] == "."):
            raise ValueError(f"invalid value path {shown!r} at {path[pos : pos + 20]!r}")
        if match.group(1) is not None:
            if pos > 0 and path[pos] != ".":
                raise ValueError(f"invalid value path {shown!r}: keys must be separated by '.'")
            steps.append(match.group(1))
        else:
            steps.append(int(match.group(2)))
        pos = match.end()
        if len(steps) > MAX_STEPS:
            raise ValueError(f"value path {shown!r} is deeper than {MAX_STEPS} steps")
    return tuple(steps)


def split_value_path(text: str) -> tuple[str, Steps]:
    """``"odom(header.stamp)"`` → ``("odom", ("header", "stamp"))``; a plain
    name has no steps. The attribute name is not checked here (callers
    apply the naming rule of their layer)."""
    open_at = text.find("(")
    if open_at < 0:
        return text, ()
    attr, inner = text[:open_at], text[open_at + 1 :]
    if not inner.endswith(")") or not inner[:-1]:
        raise ValueError(f"invalid value path {text[:80]!r}: expected attr(key.key[0]...)")
    return attr, parse_steps(inner[:-1], text)


def steps_text(steps: Steps) -> str:
    """The steps as written: ``("pose", "covariance", 0)`` → ``pose.covariance[0]``."""
    out = ""
    for step in steps:
        out += f"[{step}]" if isinstance(step, int) else (f".{step}" if out else step)
    return out


_MISSING = object()


def extract(value: object, steps: Steps) -> object:
    """Follow ``steps`` into a decoded JSON value; ``None`` where it leads nowhere."""
    for step in steps:
        if isinstance(step, int):
            if type(value) is list and step < len(value):
                value = value[step]
                continue
            return None
        if type(value) is dict:
            value = value.get(step, _MISSING)
            if value is _MISSING:
                return None
            continue
        return None
    return value
