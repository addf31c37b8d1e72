"""What an aircraft core returns: typed events inside the process, wire dicts only at the shell.

Each live core (:mod:`aircraft.core`) and the navigator's journal (:mod:`aircraft.journal`) return
these; :meth:`to_msg` gives the message of the wire schema (``net/messages.py``: ``ac_truth``,
``ac_estimate``, ``ac_status``, ``ac_init``, ``ac_input``), which the node encodes and publishes and
the offline re-flight compares. ``seq`` is the aircraft's per-kind counter, drawn when the event is
made; ``stamp_s`` is the event's fleet time (``t_s``; the journal's: its last entry's).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar


@dataclass(frozen=True, slots=True)
class AcTruth:
    """World side: the true position and velocity (network frame) at a measured broadcast's reception."""

    kind: ClassVar[str] = "ac_truth"
    src: str
    seq: int
    t_s: float
    pos_m: list[float]
    vel_m_s: list[float]

    def to_msg(self) -> dict[str, Any]:
        return {"kind": self.kind, "src": self.src, "seq": self.seq, "stamp_s": self.t_s, "t_s": self.t_s,
                "pos_m": self.pos_m, "vel_m_s": self.vel_m_s}


@dataclass(frozen=True, slots=True)
class AcEstimate:
    """One navigator's published estimate: position (3,) and its covariance (3, 3), network frame;
    optional velocity and its covariance, integrity (``hpl_m``, ``vpl_m``, ``excluded`` station ids)
    and ``extra`` named scalars (attitude, clock, IMU; docs/ins.md)."""

    kind: ClassVar[str] = "ac_estimate"
    src: str
    seq: int
    t_s: float
    algo: str
    pos_m: list[float]
    cov_m2: list[list[float]]
    n_updates: int
    vel_m_s: list[float] | None = None
    vel_cov: list[list[float]] | None = None
    hpl_m: float | None = None
    vpl_m: float | None = None
    excluded: list[int] | None = None
    extra: dict[str, float] | None = None

    def to_msg(self) -> dict[str, Any]:
        m = {"kind": self.kind, "src": self.src, "seq": self.seq, "stamp_s": self.t_s, "t_s": self.t_s,
             "pos_m": self.pos_m, "cov_m2": self.cov_m2, "algo": self.algo, "n_updates": self.n_updates}
        for k in ("vel_m_s", "vel_cov", "hpl_m", "vpl_m", "excluded", "extra"):
            v = getattr(self, k)
            if v is not None:
                m[k] = v
        return m


@dataclass(frozen=True, slots=True)
class AcStatus:
    """What a navigator is doing (docs/aircraft.md "Cold start"), with its counters."""

    kind: ClassVar[str] = "ac_status"
    src: str
    seq: int
    t_s: float
    algo: str
    state: str
    detail: str
    counts: dict[str, float]

    def to_msg(self) -> dict[str, Any]:
        return {"kind": self.kind, "src": self.src, "seq": self.seq, "stamp_s": self.t_s, "t_s": self.t_s,
                "algo": self.algo, "state": self.state, "detail": self.detail, "counts": self.counts}


@dataclass(frozen=True, slots=True)
class JournalEvent:
    """The navigator's journal on the wire: ``ac_init`` (``body = {"record": ...}``) or ``ac_input``
    (``body = {"entries": [...]}``), :mod:`aircraft.journal`."""

    kind: str
    src: str
    seq: int
    stamp_s: float
    body: dict[str, Any]

    def to_msg(self) -> dict[str, Any]:
        return {"kind": self.kind, "src": self.src, "seq": self.seq, "stamp_s": self.stamp_s, **self.body}


AcEvent = AcTruth | AcEstimate | AcStatus | JournalEvent


def to_msgs(events) -> list[dict[str, Any]]:
    """The wire messages of ``events`` (in order)."""
    return [e.to_msg() for e in events]
