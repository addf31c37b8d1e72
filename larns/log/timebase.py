"""One timebase for a recording: wall (log / publish) time in ns and fleet time in seconds.

Fleet time is seconds since the fleet epoch, scaled by the run's ``speed`` (both from the
recording's ``larns`` metadata). A recording without an epoch counts fleet time from its first
message instead.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Timebase:
    """Converts wall-clock ns stamps (``log_time``, ``publish_time``) to fleet seconds.

    Parameters
    ----------
    epoch_unix_s : the fleet epoch (Unix s), or None if the recording does not name one.
    speed : fleet seconds per wall second.
    t0_ns : first log time of the recording (fleet time 0 without an epoch).
    """

    epoch_unix_s: float | None = None
    speed: float = 1.0
    t0_ns: int = 0

    @classmethod
    def of(cls, logs, t0_ns: int = 0) -> "Timebase":
        """The timebase of (the first of) several logs."""
        if not logs:
            return cls(None, 1.0, t0_ns)
        return cls(logs[0].epoch_unix_s, logs[0].speed, t0_ns)

    def fleet_s(self, t_ns: int) -> float:
        """Fleet seconds of a wall-clock ns stamp."""
        if self.epoch_unix_s is None:
            return (t_ns - self.t0_ns) * 1e-9
        return (t_ns * 1e-9 - self.epoch_unix_s) * self.speed

    @staticmethod
    def latency_ms(log_ns: int, publish_ns: int) -> float:
        """Receive minus send stamp, wall ms."""
        return (log_ns - publish_ns) * 1e-6
