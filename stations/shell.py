"""What a station shell publishes around its core: written once, used by every shell.

:class:`PublishPolicy` is a pure object (no bus, no clock, no RNG): core outputs and the shell's
state go in, messages to publish come out. The Zenoh station process (``stations/node.py``), the
in-process simulator (``stations/sim.py``, journals optional), offline re-estimation
(``larns/analysis/offline.py``) and the replay benchmark (``larns/bench/replay.py``) all use it, so a
recording synthesized in the simulator, a live recording and an offline re-run carry the same
decorations:

* ``estimate``: the core's estimate plus the station's TDMA ``slot`` (when it holds one) and, where
  the shell counts them, the number of received messages it ``dropped`` as malformed;
* ``truth``: for each estimate, the station's true position (and, where the shell knows the true
  clocks, its true clock error against network time - the ensemble of the station's clock filter on
  the true clocks, :func:`true_clock_error_s`), for the recorder and analysis only;
* the core journal (``docs/protocol.md``, "Core journal"): ``core_init`` at power-on and every
  :attr:`PublishPolicy.init_every_navs` own navs, ``core_input`` (what the core consumed) after
  each own nav; a ``core_input`` too big for one message is split (:meth:`encode_journal`).
"""

from __future__ import annotations

import math
from typing import Any, Callable

from net import messages as M
from net.clock import true_network_offset_s

JOURNAL_INIT_EVERY_NAVS = 10  # a core_init every 10 own navs: a late recorder can still rebuild the core


def true_clock_error_s(clk: Any, clocks: dict, sid: int, t_true_s: float) -> float | None:
    """World side: the true offset of station ``sid``'s clock against network time at true time
    ``t_true_s``, network time being the ensemble as this station's clock filter ``clk`` defines it
    (members, weights and continuity terms: ``clk.scale_log``) evaluated on the true clocks
    (``clocks``: id -> oscillator). None if a member's true clock is not in ``clocks``."""
    try:
        v = true_network_offset_s(clocks, clk.scale_log, sid, t_true_s)
    except KeyError:
        return None
    return v if math.isfinite(v) else None


class PublishPolicy:
    """The publishing state of one station shell.

    Parameters
    ----------
    station_id : the station's id (``src`` of the truth and journal messages).
    journal : publish the core journal (``core_init``, ``core_input``).
    init_every_navs : a ``core_init`` every this many own navs (and at power-on).
    """

    def __init__(self, station_id: int, *, journal: bool = False,
                 init_every_navs: int = JOURNAL_INIT_EVERY_NAVS):
        self.id = int(station_id)
        self.journal = bool(journal)
        self.init_every_navs = int(init_every_navs)
        self.navs_sent = 0
        self.truth_seq = 0
        self.journal_seq = {"core_init": 0, "core_input": 0}

    # ------------------------------------------------------------------ estimate and truth
    @staticmethod
    def estimate(est: dict, slot: int | None, dropped: int | None = None) -> dict:
        """The published ``estimate``: the core's one plus ``slot`` (if any) and ``dropped`` (if the
        shell counts drops). Returns a new dict; ``est`` is not modified."""
        m = dict(est)
        if slot is not None:
            m["slot"] = int(slot)
        if dropped is not None:
            m["dropped"] = int(dropped)
        return m

    def truth(self, est: dict, t_s: float, pos_m: Any, clock_error_s: float | None = None) -> dict:
        """The ``truth`` message published beside estimate ``est`` (same ``stamp_s``): true position,
        fleet time ``t_s`` of publication and, if given, the true clock error against network time."""
        self.truth_seq += 1
        m = {"kind": "truth", "src": self.id, "seq": self.truth_seq, "stamp_s": float(est["stamp_s"]),
             "t_s": float(t_s), "pos_m": pos_m}
        if clock_error_s is not None:
            m["clock_error_s"] = float(clock_error_s)
        return m

    # ------------------------------------------------------------------ journal
    def start(self, core: Any) -> list[tuple[str, dict]]:
        """Power-on of ``core``: switches its input journal on (if journalling) and returns the
        journal items to publish, ``[(kind, fields)]``."""
        if not self.journal:
            return []
        core.journal = True
        return [("core_init", {"record": core.init_record})]

    def sent(self, kind: str) -> None:
        """The shell published an output of this kind (navs are counted for the journal's rhythm)."""
        if kind == "nav":
            self.navs_sent += 1

    def after_outputs(self, core: Any, outs: list[dict]) -> list[tuple[str, dict]]:
        """Journal items due after the shell handled ``outs`` (call :meth:`sent` for each published
        output first): after an own nav, ``core_init`` every ``init_every_navs`` navs, then the
        ``core_input`` of everything the core consumed since the last one."""
        if not self.journal or not any(m["kind"] == "nav" for m in outs):
            return []
        items: list[tuple[str, dict]] = []
        if self.navs_sent % self.init_every_navs == 0:
            items.append(("core_init", {"record": core.init_record}))
        items.append(("core_input", {"entries": core.take_inputs()}))
        return items

    def journal_msg(self, kind: str, stamp_s: float, **fields: Any) -> dict:
        """A journal message with the next sequence number of its kind."""
        self.journal_seq[kind] += 1
        return {"kind": kind, "src": self.id, "seq": self.journal_seq[kind], "stamp_s": float(stamp_s), **fields}

    def encode_journal(self, kind: str, fields: dict, stamp_s: float,
                       on_error: Callable[[str, int, M.MessageError], None] | None = None
                       ) -> list[tuple[str, bytes]]:
        """Encode one journal item as ``[(key, bytes)]``. A ``core_input`` too big for one message is
        split in halves until it fits (consecutive sequence numbers, same ``stamp_s``). What cannot be
        encoded is reported to ``on_error(kind, n_entries, error)`` and left out."""
        if kind == "core_init":
            m = self.journal_msg("core_init", stamp_s, **fields)
            try:
                return [(M.key_for(m), M.encode(m))]
            except M.MessageError as e:
                if on_error:
                    on_error(kind, 0, e)
                return []
        out: list[tuple[str, bytes]] = []
        chunks = [fields["entries"]]
        while chunks:
            part = chunks.pop(0)
            m = self.journal_msg("core_input", stamp_s, entries=part)
            try:
                if len(part) > M.MAX_JOURNAL:
                    raise M.MessageError("shape", f"{len(part)} journal entries > {M.MAX_JOURNAL}")
                # not validated again here: every entry is a timer time or a message that was
                # validated when it was received or sent; readers validate. Encoding a cycle's
                # journal at N = 50 takes 0.12 ms instead of 0.93 ms.
                data = M.encode(m, validate=False)
            except M.MessageError as e:
                if e.reason in ("size", "shape") and len(part) > 1:  # too big for one message: split
                    self.journal_seq["core_input"] -= 1
                    half = len(part) // 2
                    chunks[:0] = [part[:half], part[half:]]
                    continue
                if on_error:
                    on_error(kind, len(part), e)
                continue
            out.append((M.key_for(m), data))
        return out
