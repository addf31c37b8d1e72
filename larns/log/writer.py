"""Writing MCAP files: :class:`LogWriter` (indexed, chunked, zstd), used by the recorder
(``larns record``, :class:`larns.log.record.McapSink`), ``larns export``, ``larns recover``, offline
re-estimation and the replay benchmark."""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger("larns.log")


class LogWriteError(OSError):
    """Writing the log failed (disk full, file-size limit, I/O error); the file was finished with
    what had been written by then (:attr:`LogWriter.error`)."""


class _CountingFile:
    """The output file as the MCAP writer sees it: counts the bytes handed over (``tell``)."""

    def __init__(self, f):
        self.f = f
        self.n = 0

    def write(self, data) -> int:
        self.f.write(data)
        self.n += len(data)
        return len(data)

    def tell(self) -> int:
        return self.n

    def flush(self) -> None:
        self.f.flush()

    def close(self) -> None:
        self.f.close()


class LogWriter:
    """An indexed, chunked (zstd) MCAP writer keyed by topic; registers channels and schemas lazily.

    ``write(topic, data, log_time, publish_time)`` for msgpack wire bytes (schemaless, like
    ``larns record``); ``write(topic, data, ..., encoding="json", schema=(name, json_schema_bytes))``
    for JSON channels.

    No data lost on a full disk: a write that fails (``OSError``: no space, the file-size limit, an
    I/O error) stops the writer: the file is cut back to the end of the last chunk written whole and
    closed with a data-end record and a footer, so it opens as a complete file; later writes are
    refused with :class:`LogWriteError` (``error`` holds the reason).
    """

    def __init__(self, path: str | Path, metadata: dict[str, dict[str, str]] | None = None,
                 library: str = "larns", chunk_size: int = 1 << 20):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = _CountingFile(open(self.path, "wb"))
        self.writer = Writer(self._f, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        self.error: str | None = None
        self._good = 0  # file offset after the last record written whole (a chunk, the header)
        self._guard(lambda: self.writer.start(profile="", library=library))
        self.channels: dict[tuple[str, str], int] = {}
        self.schemas: dict[tuple[str, bytes], int] = {}
        self.seq: dict[int, int] = {}
        self.count = 0
        self.finished = False
        for name, md in (metadata or {}).items():
            self._guard(lambda: self.writer.add_metadata(name, {str(k): str(v) for k, v in md.items()}))

    def metadata(self, name: str, md: dict[str, str]) -> None:
        """Add a metadata record (anywhere in the file: ``larns recover`` copies them as they come)."""
        self._guard(lambda: self.writer.add_metadata(name, {str(k): str(v) for k, v in md.items()}))

    def _guard(self, op) -> None:
        """Run a writer operation; on ``OSError`` finish the file with what it has (class docstring)."""
        if self.error is not None:
            raise LogWriteError(self.error)
        try:
            op()
            self._f.flush()  # to the OS now: a failing write shows here, not at close
            self._good = self._f.tell()
        except OSError as e:
            self._salvage(e)
            raise LogWriteError(self.error) from None

    def _salvage(self, e: OSError) -> None:
        """Cut the file back to the last whole record and end it with DataEnd + Footer + magic."""
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer
        from mcap.writer import MCAP0_MAGIC

        self.error = f"{e.strerror or type(e).__name__} writing {self.path}"
        self.finished = True
        try:
            self._f.close()  # (its buffer may fail again: the file is cut below)
        except OSError:
            pass
        b = RecordBuilder()
        DataEnd(0).write(b)
        Footer(0, 0, 0).write(b)
        tail = b.end() + MCAP0_MAGIC
        try:
            fd = os.open(self.path, os.O_WRONLY)
            try:
                os.ftruncate(fd, self._good)
                if self._good > 0:  # (a file without its header stays empty)
                    os.pwrite(fd, tail, self._good)
            finally:
                os.close(fd)
        except OSError as e2:
            self.error += f"; the file could not be finished either ({e2.strerror or type(e2).__name__})"
        log.error("%s", self.error)

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
        if self.error is not None:
            raise LogWriteError(self.error)
        ch = self.channel(topic, encoding, schema, channel_metadata)
        seq = self.seq[ch] if sequence is None else sequence
        pos = self._f.n
        try:
            self.writer.add_message(channel_id=ch, log_time=int(log_time), data=data,
                                    publish_time=int(log_time if publish_time is None else publish_time),
                                    sequence=seq)
        except OSError as e:
            self._salvage(e)
            raise LogWriteError(self.error) from None
        if self._f.n != pos:  # the message closed a chunk: it went to the file
            self._guard(lambda: None)
        self.seq[ch] += 1
        self.count += 1

    def flush(self) -> None:
        """Finish the current chunk: what is written so far survives a SIGKILL."""
        self._guard(self.writer.flush)

    def finish(self) -> None:
        """Write the summary and footer and close the file (a no-op after a write error: the
        file was finished then)."""
        if not self.finished:
            self._guard(self.writer.finish)
            self.finished = True
            self._f.close()

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.finish()
