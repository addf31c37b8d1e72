"""JSON Schemas of the Foxglove SDK's typed messages, generated from the SDK's own schemas.

The live view (``larns view``, :mod:`larns.viz.live`) sends the SDK's typed messages (protobuf); the
recorder and ``larns export`` write the same messages as JSON (:mod:`larns.viz.foxglove`). Both use
one definition: the SDK's schema (``foxglove.messages.<Name>.get_schema()``, a protobuf
``FileDescriptorSet``), turned here into the JSON Schema of its JSON form - Foxglove's JSON
conventions: ``google.protobuf.Timestamp`` / ``Duration`` as ``{"sec", "nsec"}``, enums as integers,
``bytes`` as base64 strings, every field present (``required``).

Pure functions; the descriptor set is read with a small proto3 wire-format reader (no protobuf package).
"""

from __future__ import annotations

import json
from functools import lru_cache

# FieldDescriptorProto.type values
_DOUBLE, _FLOAT, _INT64, _UINT64, _INT32, _FIXED64, _FIXED32, _BOOL, _STRING = 1, 2, 3, 4, 5, 6, 7, 8, 9
_MESSAGE, _BYTES, _UINT32, _ENUM, _SFIXED32, _SFIXED64, _SINT32, _SINT64 = 11, 12, 13, 14, 15, 16, 17, 18
_UNSIGNED = {_UINT64, _FIXED64, _FIXED32, _UINT32}
_TIME_TYPES = {"google.protobuf.Timestamp": 0, "google.protobuf.Duration": None}  # minimum of sec


def _varint(b: bytes, i: int) -> tuple[int, int]:
    out = shift = 0
    while True:
        c = b[i]
        i += 1
        out |= (c & 0x7F) << shift
        if not c & 0x80:
            return out, i
        shift += 7


def _fields(b: bytes) -> dict[int, list]:
    """Field number -> values (ints for varints, bytes for length-delimited) of one message."""
    out: dict[int, list] = {}
    i = 0
    while i < len(b):
        tag, i = _varint(b, i)
        num, wt = tag >> 3, tag & 7
        if wt == 0:
            v, i = _varint(b, i)
        elif wt == 2:
            n, i = _varint(b, i)
            v, i = b[i:i + n], i + n
        elif wt in (1, 5):
            n = 8 if wt == 1 else 4
            v, i = b[i:i + n], i + n
        else:
            raise ValueError(f"descriptor: wire type {wt}")
        out.setdefault(num, []).append(v)
    return out


def descriptors(fds: bytes) -> dict[str, list[tuple[str, int, bool, str]]]:
    """Full message name -> [(field name, type, repeated, type name)] of a ``FileDescriptorSet``."""
    out: dict[str, list] = {}

    def message(m: bytes, prefix: str) -> None:
        md = _fields(m)
        name = f"{prefix}.{md[1][0].decode()}" if prefix else md[1][0].decode()
        out[name] = []
        for f in md.get(2, []):
            fd = _fields(f)
            tname = fd[6][0].decode().lstrip(".") if 6 in fd else ""
            out[name].append((fd[1][0].decode(), fd[5][0], fd.get(4, [1])[0] == 3, tname))
        for nested in md.get(3, []):
            message(nested, name)

    for f in _fields(fds).get(1, []):
        fd = _fields(f)
        for m in fd.get(4, []):
            message(m, fd[2][0].decode() if 2 in fd else "")
    return out


def _field_schema(typ: int, tname: str, msgs: dict) -> dict:
    if typ == _MESSAGE:
        return _object(tname, msgs)
    if typ in (_DOUBLE, _FLOAT):
        return {"type": "number"}
    if typ == _BOOL:
        return {"type": "boolean"}
    if typ == _STRING:
        return {"type": "string"}
    if typ == _BYTES:
        return {"type": "string", "contentEncoding": "base64"}
    if typ == _ENUM:
        return {"type": "integer"}
    return {"type": "integer", "minimum": 0} if typ in _UNSIGNED else {"type": "integer"}


def _object(name: str, msgs: dict) -> dict:
    if name in _TIME_TYPES:
        sec = {"type": "integer"} if _TIME_TYPES[name] is None else {"type": "integer", "minimum": 0}
        return {"type": "object", "title": name,
                "properties": {"sec": sec, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
                "required": ["sec", "nsec"]}
    props = {}
    for fname, typ, rep, tname in msgs[name]:
        s = _field_schema(typ, tname, msgs)
        props[fname] = {"type": "array", "items": s} if rep else s
    return {"type": "object", "title": name, "properties": props, "required": list(props)}


@lru_cache(maxsize=None)
def json_schema(name: str) -> dict:
    """The JSON Schema (draft 7) of the JSON form of the SDK's message ``name`` (e.g.
    ``"foxglove.SceneUpdate"``), from ``foxglove.messages.<Name>.get_schema()``."""
    import foxglove.messages as fm

    schema = getattr(fm, name.removeprefix("foxglove.")).get_schema()
    if schema.encoding != "protobuf" or schema.name != name:
        raise ValueError(f"{name}: unexpected SDK schema {schema.name} ({schema.encoding})")
    out = _object(name, descriptors(bytes(schema.data)))
    out["$schema"] = "http://json-schema.org/draft-07/schema#"
    out["description"] = f"JSON form of the Foxglove SDK's {name} (generated from its protobuf schema)"
    return out


def json_schema_bytes(name: str) -> bytes:
    return json.dumps(json_schema(name), sort_keys=True).encode()
