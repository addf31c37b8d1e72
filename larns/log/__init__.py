"""The recording model: reading MCAP logs (complete or killed, several merged), one timebase, key
expressions, the writer, and the typed series every tool reads (:mod:`larns.log.series`).

* :mod:`larns.log.reader` - stream-read MCAP files (:func:`read_log`, :func:`merge`);
* :mod:`larns.log.series` - decode once into per-station / per-aircraft / network series
  (:func:`load`, :class:`Recording`); the only module that decodes recorded wire messages;
* :mod:`larns.log.timebase` - fleet / wall / publish time;
* :mod:`larns.log.keyexpr` - Zenoh-style globs and ``--remap`` rules;
* :mod:`larns.log.writer` - :class:`LogWriter`.
"""

from .keyexpr import keyexpr_match, parse_remaps, remap, topic_selected
from .reader import LogFile, Msg, merge, read_log, read_logs
from .timebase import Timebase
from .writer import LogWriter

__all__ = ["LogFile", "LogWriter", "Msg", "Timebase", "keyexpr_match", "merge", "parse_remaps", "read_log",
           "read_logs", "remap", "topic_selected"]
