"""Writing MCAP files: :class:`LogWriter` (indexed, chunked, zstd), used by the recorder
(``larns record``, :class:`larns.log.record.McapSink`), ``larns export``, ``larns recover``, offline
re-estimation and the replay benchmark."""

from __future__ import annotations

from pathlib import Path


class LogWriter:
    """An indexed, chunked (zstd) MCAP writer keyed by topic; registers channels and schemas lazily.

    ``write(topic, data, log_time, publish_time)`` for msgpack wire bytes (schemaless, like
    ``larns record``); ``write(topic, data, ..., encoding="json", schema=(name, json_schema_bytes))``
    for JSON channels.
    """

    def __init__(self, path: str | Path, metadata: dict[str, dict[str, str]] | None = None,
                 library: str = "larns", chunk_size: int = 1 << 20):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self.writer = Writer(self._f, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        self.writer.start(profile="", library=library)
        self.channels: dict[tuple[str, str], int] = {}
        self.schemas: dict[tuple[str, bytes], int] = {}
        self.seq: dict[int, int] = {}
        self.count = 0
        for name, md in (metadata or {}).items():
            self.writer.add_metadata(name, {str(k): str(v) for k, v in md.items()})
        self.finished = False

    def channel(self, topic: str, encoding: str = "msgpack", schema: tuple[str, bytes] | None = None,
                metadata: dict[str, str] | None = None) -> int:
        """The channel id of ``topic`` (registered on first use, with ``metadata``; default
        ``{"source": "larns"}``)."""
        ch = self.channels.get((topic, encoding))
        if ch is None:
            sid = 0
            if schema is not None:
                sid = self.schemas.get(schema)
                if sid is None:
                    sid = self.writer.register_schema(name=schema[0], encoding="jsonschema", data=schema[1])
                    self.schemas[schema] = sid
            ch = self.writer.register_channel(topic=topic, message_encoding=encoding, schema_id=sid,
                                              metadata=metadata or {"source": "larns"})
            self.channels[(topic, encoding)] = ch
            self.seq[ch] = 0
        return ch

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int | None = None,
              encoding: str = "msgpack", schema: tuple[str, bytes] | None = None,
              sequence: int | None = None, channel_metadata: dict[str, str] | None = None) -> None:
        ch = self.channel(topic, encoding, schema, channel_metadata)
        seq = self.seq[ch] if sequence is None else sequence
        self.writer.add_message(channel_id=ch, log_time=int(log_time), data=data,
                                publish_time=int(log_time if publish_time is None else publish_time),
                                sequence=seq)
        self.seq[ch] += 1
        self.count += 1

    def flush(self) -> None:
        """Finish the current chunk: what is written so far survives a SIGKILL."""
        self.writer.flush()

    def finish(self) -> None:
        if not self.finished:
            self.finished = True
            self.writer.finish()
            self._f.close()

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.finish()
