"""What ``larns.mcaputil`` offered, now from :mod:`larns.log` (old name kept for one release)."""

from .keyexpr import keyexpr_match, parse_remaps, remap, topic_selected  # noqa: F401
from .reader import LogFile, Msg, merge, read_log, read_logs  # noqa: F401
from .series import decode_all  # noqa: F401
from .timebase import Timebase  # noqa: F401
from .writer import LogWriter  # noqa: F401
