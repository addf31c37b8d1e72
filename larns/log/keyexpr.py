"""Zenoh-style key-expression globs for selecting and renaming recorded channels.

``*`` matches one chunk (no ``/``) or part of one, ``**`` any number of chunks
(:func:`keyexpr_match`); ``--remap FROM=TO`` rules rename keys on replay (:func:`remap`).
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Sequence


@lru_cache(maxsize=512)
def _chunk_re(chunk: str) -> re.Pattern:
    return re.compile("^" + "".join("[^/]*" if c == "*" else re.escape(c)
                                    for c in re.split(r"(\*)", chunk) if c) + "$")


def _match_chunks(pat: tuple[str, ...], key: tuple[str, ...]) -> bool:
    if not pat:
        return not key
    if pat[0] == "**":
        return any(_match_chunks(pat[1:], key[i:]) for i in range(len(key) + 1))
    return bool(key) and bool(_chunk_re(pat[0]).match(key[0])) and _match_chunks(pat[1:], key[1:])


def keyexpr_match(pattern: str, key: str) -> bool:
    """Zenoh-style glob: ``*`` = one chunk (or part of one), ``**`` = any number of chunks.

    >>> keyexpr_match("larns/station/*/nav", "larns/station/12/nav")
    True
    >>> keyexpr_match("larns/**", "larns/station/1/range/req/2")
    True
    >>> keyexpr_match("**/estimate", "larns/station/3/estimate")
    True
    """
    return _match_chunks(tuple(pattern.strip("/").split("/")), tuple(key.strip("/").split("/")))


def topic_selected(topic: str, include: Sequence[str] | None, exclude: Sequence[str] | None) -> bool:
    if include and not any(keyexpr_match(p, topic) for p in include):
        return False
    if exclude and any(keyexpr_match(p, topic) for p in exclude):
        return False
    return True


def parse_remaps(specs: Sequence[str] | None) -> list[tuple[str, str]]:
    """``["larns/station=sim/station", ...]`` -> [(from_prefix, to_prefix)]; prefix match on chunks."""
    out = []
    for s in specs or []:
        a, sep, b = s.partition("=")
        if not sep or not a or not b:
            raise ValueError(f"--remap {s!r}: expected FROM=TO")
        out.append((a.strip("/"), b.strip("/")))
    return out


def remap(topic: str, rules: Sequence[tuple[str, str]]) -> str:
    """First matching rule wins. ``FROM`` may be a whole key or a key prefix (whole chunks) or a glob
    (then the whole key is replaced by ``TO``)."""
    for a, b in rules:
        if topic == a:
            return b
        if topic.startswith(a + "/"):
            return b + topic[len(a):]
        if "*" in a and keyexpr_match(a, topic):
            return b
    return topic
