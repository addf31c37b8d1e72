"""A Foxglove WebSocket protocol client for the tests (``websockets``), with a schema-driven decoder.

Speaks the Foxglove WebSocket protocol (subprotocol ``foxglove.sdk.v1``): reads ``serverInfo``,
``advertise``, subscribes to every channel, collects ``messageData`` (op 1) and ``time`` (op 2)
frames, sends playback-control requests (op 3). Messages are decoded by their advertised schema:
``json`` channels with ``json`` (and validated against their JSON Schema), ``protobuf`` channels by a
small proto3 decoder driven by the channel's own ``FileDescriptorSet`` (no protobuf package needed).
"""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import time
from dataclasses import dataclass, field

import websockets

SUBPROTOCOL = "foxglove.sdk.v1"


# --------------------------------------------------------------------------- proto3 wire format

def _varint(b: bytes, i: int) -> tuple[int, int]:
    out = shift = 0
    while True:
        if i >= len(b):
            raise ValueError("truncated varint")
        c = b[i]
        i += 1
        out |= (c & 0x7F) << shift
        if not c & 0x80:
            return out, i
        shift += 7
        if shift > 63:
            raise ValueError("varint too long")


def wire_fields(b: bytes) -> list[tuple[int, int, object]]:
    """(field number, wire type, int or bytes) of every field; raises on any malformed byte."""
    out, i = [], 0
    while i < len(b):
        tag, i = _varint(b, i)
        num, wt = tag >> 3, tag & 7
        if num == 0:
            raise ValueError("field number 0")
        if wt == 0:
            v, i = _varint(b, i)
        elif wt == 1:
            v, i = b[i:i + 8], i + 8
        elif wt == 5:
            v, i = b[i:i + 4], i + 4
        elif wt == 2:
            n, i = _varint(b, i)
            v, i = b[i:i + n], i + n
        else:
            raise ValueError(f"wire type {wt}")
        if i > len(b):
            raise ValueError("truncated field")
        out.append((num, wt, v))
    return out


def _fields_by_num(b: bytes) -> dict[int, list]:
    d: dict[int, list] = {}
    for num, _wt, v in wire_fields(b):
        d.setdefault(num, []).append(v)
    return d


def _str(v) -> str:
    return bytes(v).decode()


class ProtoSchema:
    """Message descriptors of a ``FileDescriptorSet``: full name -> {number: (name, type, repeated,
    type name)}."""

    def __init__(self, fds: bytes):
        self.messages: dict[str, dict[int, tuple[str, int, bool, str]]] = {}
        for f in _fields_by_num(fds).get(1, []):
            fd = _fields_by_num(f)
            pkg = _str(fd[2][0]) if 2 in fd else ""
            for m in fd.get(4, []):
                self._message(m, pkg)

    def _message(self, m: bytes, prefix: str) -> None:
        md = _fields_by_num(m)
        name = (prefix + "." if prefix else "") + _str(md[1][0])
        fields = {}
        for f in md.get(2, []):
            fd = _fields_by_num(f)
            fields[fd[3][0]] = (_str(fd[1][0]), fd[5][0], fd.get(4, [1])[0] == 3,
                                _str(fd[6][0]).lstrip(".") if 6 in fd else "")
        self.messages[name] = fields
        for nested in md.get(3, []):
            self._message(nested, name)

    def decode(self, type_name: str, b: bytes) -> dict:
        """The message as a dict (field names of the schema); raises on unknown fields or bad bytes."""
        desc = self.messages[type_name]
        out: dict = {}
        for num, wt, v in wire_fields(b):
            if num not in desc:
                raise ValueError(f"{type_name}: unknown field {num}")
            name, typ, rep, tname = desc[num]
            vals = self._scalars(typ, wt, v, tname)
            if rep:
                out.setdefault(name, []).extend(vals)
            else:
                out[name] = vals[-1]
        return out

    def _scalars(self, typ: int, wt: int, v, tname: str) -> list:
        if typ == 11:
            return [self.decode(tname, v)]
        if typ == 9:
            return [_str(v)]
        if typ == 12:
            return [bytes(v)]
        if wt == 2:  # packed repeated numbers
            if typ == 1:
                return list(struct.unpack(f"<{len(v) // 8}d", v))
            vals, i = [], 0
            while i < len(v):
                x, i = _varint(v, i)
                vals.append(x)
            return vals
        if typ == 1:
            return [struct.unpack("<d", v)[0]]
        if typ == 2:
            return [struct.unpack("<f", v)[0]]
        if typ == 7:
            return [struct.unpack("<I", v)[0]]
        if typ == 6:
            return [struct.unpack("<Q", v)[0]]
        return [v]  # varint kinds: int, uint, bool, enum


# --------------------------------------------------------------------------- the client

@dataclass
class Received:
    """What a client saw: server info, channels by id, decoded messages, server times."""

    info: dict = field(default_factory=dict)
    channels: dict[int, dict] = field(default_factory=dict)
    messages: list[tuple[float, str, int, dict]] = field(default_factory=list)  # (arrival wall s, topic, log ns, msg)
    times_ns: list[int] = field(default_factory=list)
    text: list[dict] = field(default_factory=list)
    undecodable: list[str] = field(default_factory=list)

    def of(self, topic: str) -> list[dict]:
        return [m for _, t, _, m in self.messages if t == topic]

    def topics(self) -> set[str]:
        return {t for _, t, _, _ in self.messages}


class FoxgloveClient:
    """Connects, subscribes to every advertised channel and decodes what arrives."""

    def __init__(self, url: str):
        self.url = url
        self.got = Received()
        self._schemas: dict[int, object] = {}
        self._validators: dict[int, object] = {}
        self._raw: list[tuple[float, bytes]] = []
        self.ws = None

    async def __aenter__(self) -> "FoxgloveClient":
        self.ws = await websockets.connect(self.url, subprotocols=[SUBPROTOCOL], max_size=None)
        return self

    async def __aexit__(self, *exc) -> None:
        await self.ws.close()

    async def send(self, obj) -> None:
        await self.ws.send(json.dumps(obj) if isinstance(obj, dict) else obj)

    async def playback(self, command: int, speed: float = 1.0, seek_ns: int | None = None,
                       request_id: str = "r") -> None:
        """Playback-control request (binary op 3): command 0 play / 1 pause, speed, optional seek."""
        rid = request_id.encode()
        frame = struct.pack("<BBfB", 3, command, speed, 1 if seek_ns is not None else 0)
        frame += struct.pack("<Q", seek_ns or 0) + struct.pack("<I", len(rid)) + rid
        await self.send(frame)

    async def run(self, seconds: float, until=None) -> Received:
        """Read for ``seconds`` (or until ``until(received)`` is true)."""
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end and not (until and until(self.got)):
            try:
                frame = await asyncio.wait_for(self.ws.recv(), timeout=max(0.05, t_end - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(frame, str):
                await self._text(json.loads(frame))
            else:
                self._raw.append((time.time(), frame))  # decoded after reading: the clock sees arrivals
                if until is not None:
                    self._decode_raw()
        self._decode_raw()
        return self.got

    def _decode_raw(self) -> None:
        for wall, frame in self._raw:
            self._binary(frame, wall)
        self._raw.clear()

    async def _text(self, d: dict) -> None:
        self.got.text.append(d)
        if d["op"] == "serverInfo":
            self.got.info = d
        elif d["op"] == "advertise":
            subs = []
            for c in d["channels"]:
                self.got.channels[c["id"]] = c
                self._prepare(c)
                subs.append({"id": c["id"], "channelId": c["id"]})
            await self.send({"op": "subscribe", "subscriptions": subs})

    def _prepare(self, c: dict) -> None:
        if c["encoding"] == "protobuf":
            self._schemas[c["id"]] = ProtoSchema(base64.b64decode(c["schema"]))
        elif c["encoding"] == "json" and c.get("schemaEncoding") == "jsonschema":
            import jsonschema

            self._validators[c["id"]] = jsonschema.Draft7Validator(json.loads(c["schema"]))

    def _binary(self, b: bytes, wall: float) -> None:
        op = b[0]
        if op == 2:  # time
            self.got.times_ns.append(struct.unpack_from("<Q", b, 1)[0])
        elif op == 1:  # messageData: subscription id, log time, payload
            sub_id, log_ns = struct.unpack_from("<IQ", b, 1)
            c = self.got.channels[sub_id]
            try:
                msg = self._decode(sub_id, c, b[13:])
            except Exception as e:  # noqa: BLE001 - recorded; the tests assert there are none
                self.got.undecodable.append(f"{c['topic']}: {e!r}")
                return
            self.got.messages.append((wall, c["topic"], log_ns, msg))

    def _decode(self, cid: int, c: dict, payload: bytes) -> dict:
        if c["encoding"] == "json":
            msg = json.loads(payload)
            if cid in self._validators:
                self._validators[cid].validate(msg)
            return msg
        if c["encoding"] == "protobuf":
            return self._schemas[cid].decode(c["schemaName"], payload)
        raise ValueError(f"encoding {c['encoding']}")
