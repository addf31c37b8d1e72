"""The aircraft navigator's journal: everything the navigator consumed, in order, for exact replay.

Each aircraft core (radio :class:`aircraft.radio_core.RadioAircraftCore`, inertial
:class:`aircraft.ins_core.InsAircraftCore`, triad :class:`aircraft.triad_core.TriadAircraftCore`)
splits into a world side (truth, IMU / satellite / baro emulation, the channel layer) and a navigator
side that sees only what a receiver sees. The world hands the navigator:

* ``["m", t_rx, src, pos_m, cov_m2, clock_var_m2, rho_m]`` - one station broadcast as measured
  (reception time on the fleet axis, the broadcast station position and covariance, the broadcast
  clock variance as a range variance, the pseudorange);
* ``["imu", k0, gyro (n, 3), accel (n, 3)]`` - IMU increments of steps ``k0 .. k0 + n - 1``;
* ``["sv", k, ranges (n,), baro]`` - the triad's epoch ``k``: satellite pseudoranges of the ids the
  navigator asked for (``None`` below the mask) and the barometric height (``None`` before the start).

Entries are kept in the order the navigator consumed them and published as ``ac_input`` messages
(``larns/aircraft/<name>/input``, about one per second of fleet time), after an ``ac_init``
(``larns/aircraft/<name>/init``: the navigator's kind and settings; re-sent every
:data:`INIT_EVERY_INPUTS` inputs for a recorder that linked up late). :func:`replay` rebuilds the
navigator from the init record and feeds it the entries: it reproduces the recorded ``ac_estimate``
messages bit for bit (same code, same inputs, same order). Never truth: the world's truth goes out on
``ac_truth`` only.

Replay of the inertial navigators: a measurement is applied at the IMU step count it met live; the
IMU steps the navigator integrates while handling it (its own ``advance_to``) come after its ``m``
entry in the journal, so the replay first collects every sample and epoch by index, then walks the
entries: an ``imu`` entry integrates up to its last step, an ``m`` entry is handed to the navigator,
which pulls the samples it needs by index.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, Iterable

import numpy as np

from .events import JournalEvent

#: the init record is re-sent after this many inputs (as a station re-sends ``core_init``)
INIT_EVERY_INPUTS = 10
FLUSH_S = 1.0      # an ``ac_input`` at least once per second of fleet time ...
FLUSH_ITEMS = 512  # ... or once this many measurements / samples are pending (the schema's lists hold 1024)


class JournalHole(LookupError):
    """A replay needed an IMU sample or epoch that the recorded journal does not hold."""


class AcJournal:
    """The pending journal of one aircraft navigator; :meth:`take` returns the messages to publish
    (``ac_init``, ``ac_input``), :meth:`close` the rest at exit."""

    def __init__(self, name: str, record: dict[str, Any]):
        self.name = name
        self.record = record
        self.seq: Counter[str] = Counter()
        self.entries: list[list] = []
        self._items = 0
        self._t_first: float | None = None
        self._t_last = 0.0
        self._ready: list[JournalEvent] = [self._event("ac_init", 0.0, record=record)]

    def _add(self, t_s: float, n: int) -> None:
        if self._t_first is None:
            self._t_first = t_s
        self._t_last = t_s
        self._items += n
        if self._items >= FLUSH_ITEMS or t_s - self._t_first >= FLUSH_S:
            self.flush()

    def m(self, t_rx: float, src: int, pos_m, cov_m2, clock_var_m2: float, rho_m: float) -> None:
        self.entries.append(["m", float(t_rx), int(src), [float(x) for x in pos_m],
                             [[float(x) for x in r] for r in cov_m2], float(clock_var_m2), float(rho_m)])
        self._add(float(t_rx), 1)

    def imu(self, k: int, t_s: float, g: np.ndarray, a: np.ndarray) -> None:
        """Step ``k`` (ending at ``t_s``): gyro and accelerometer increments (3,)."""
        last = self.entries[-1] if self.entries else None
        if last is not None and last[0] == "imu" and last[1] + len(last[2]) == k:
            last[2].append(np.asarray(g, float).reshape(3).tolist())
            last[3].append(np.asarray(a, float).reshape(3).tolist())
        else:
            self.entries.append(["imu", int(k), [np.asarray(g, float).reshape(3).tolist()],
                                 [np.asarray(a, float).reshape(3).tolist()]])
        self._add(float(t_s), 1)

    def sv(self, k: int, t_s: float, z: np.ndarray, baro_m: float | None) -> None:
        self.entries.append(["sv", int(k), [None if not np.isfinite(x) else float(x) for x in np.asarray(z, float)],
                             None if baro_m is None else float(baro_m)])
        self._add(float(t_s), 1)

    def flush(self) -> None:
        if not self.entries:
            return
        self._ready.append(self._event("ac_input", self._t_last, entries=self.entries))
        self.entries, self._items, self._t_first = [], 0, None
        if self.seq["ac_input"] % INIT_EVERY_INPUTS == 0:
            self._ready.append(self._event("ac_init", self._t_last, record=self.record))

    def take(self) -> list[JournalEvent]:
        out, self._ready = self._ready, []
        return out

    def close(self) -> list[JournalEvent]:
        self.flush()
        return self.take()

    def _event(self, kind: str, stamp_s: float, **fields: Any) -> JournalEvent:
        self.seq[kind] += 1
        return JournalEvent(kind, self.name, self.seq[kind], float(stamp_s), fields)


# --------------------------------------------------------------------------- replay

class Inputs:
    """The IMU samples and triad epochs of a journal, by index (the replay's world)."""

    def __init__(self, entries: Iterable[list]):
        self.imu: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.sv: dict[int, tuple[np.ndarray, float | None]] = {}
        for e in entries:
            if e[0] == "imu":
                for i, (g, a) in enumerate(zip(e[2], e[3])):
                    self.imu[e[1] + i] = (np.array([g], float), np.array([a], float))
            elif e[0] == "sv":
                self.sv[e[1]] = (np.array([np.nan if x is None else x for x in e[2]], float), e[3])

    def sample(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        try:
            return self.imu[k]
        except KeyError:
            raise JournalHole(f"IMU step {k} not in the journal") from None

    def epoch(self, k: int) -> tuple[np.ndarray, float | None]:
        try:
            return self.sv[k]
        except KeyError:
            raise JournalHole(f"satellite epoch {k} not in the journal") from None


def navigator_from_record(record: dict[str, Any], name: str, algos: Iterable[str] | None = None,
                          inputs: Inputs | None = None):
    """The navigator of an init record, without a world: ``radio`` -> a
    :class:`aircraft.radio_core.RadioAircraftCore` running ``algos`` (default: the recorded ones),
    ``ins`` / ``triad`` -> the inertial cores fed from ``inputs``. Radio algorithms also run on an
    inertial journal's measurements (its ``m`` entries)."""
    kind = record["kind"]
    radio = [a for a in (algos or ()) if a not in ("ins-ekf", "triad")]
    if kind == "radio" or radio:
        from .radio_core import RadioAircraftCore

        return RadioAircraftCore.from_record(record, name, tuple(radio or record.get("algos", ())))
    if kind == "ins":
        from .ins_core import InsAircraftCore

        return InsAircraftCore.from_record(record, name, inputs or Inputs(()))
    from .triad_core import TriadAircraftCore

    return TriadAircraftCore.from_record(record, name, inputs or Inputs(()))


def algos_of(record: dict[str, Any]) -> tuple[str, ...]:
    """The algorithms the recorded navigator ran."""
    return {"ins": ("ins-ekf",), "triad": ("triad",)}.get(record["kind"], tuple(record.get("algos", ())))


def can_run(record: dict[str, Any], algo: str) -> bool:
    """Whether the journal of ``record`` holds the inputs of ``algo``: radio algorithms need the
    measurements (every journal), ``ins-ekf`` the IMU of an inertial journal, ``triad`` a triad's."""
    if algo == "ins-ekf":
        return record["kind"] == "ins"
    if algo == "triad":
        return record["kind"] == "triad"
    return True


def replay(record: dict[str, Any], name: str, entries: list[list], algos: Iterable[str] | None = None
           ) -> tuple[list[dict], str | None, float | None]:
    """Re-run the navigator of ``record`` on the journal ``entries`` (in order); returns the messages
    it published (``ac_estimate``, ``ac_status`` as the wire's dicts; not validated), why it stopped early if it did (a
    :class:`JournalHole`: a sample it needed was lost) and the reception time of the last
    measurement it handled."""
    algos = tuple(algos) if algos else algos_of(record)
    inputs = Inputs(entries)
    nav = navigator_from_record(record, name, algos, inputs)
    radio = hasattr(nav, "estimators")
    out: list[dict] = []
    t_last = None
    try:
        for e in entries:
            if e[0] == "m":
                out += [ev.to_msg() for ev in nav.measurement(*e[1:])]
                t_last = e[1]
            elif e[0] == "imu" and not radio:
                nav.step_to(e[1] + len(e[2]))
    except JournalHole as h:
        return out, str(h), t_last
    return out, None, t_last
