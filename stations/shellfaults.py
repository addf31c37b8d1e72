"""The emulated world's per-link channel and station faults, applied in a station's *shell*.

Both shells (the in-process simulator and the Zenoh station process) call the same object, so a
scenario's ``[[links]]`` and ``[[faults]]`` act alike in both. Nothing here reaches the estimator
directly: a liar's core estimates honestly and its shell falsifies what goes on air; a biased
antenna delays the legs on air; a clock jump steps the clock the shell reads; a bad coarse fix is
the fix the core is handed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S
from net.channel import AirChannel, with_clock_faults
from net.scenario import Scenario

LIE_KINDS = ("nav", "range_rsp", "reply")  # air messages that carry the sender's position


class ShellFaults:
    """Per-link channel and faults as seen by station ``station_id``'s shell."""

    def __init__(self, scn: Scenario, station_id: int):
        self.scn = scn
        self.id = station_id
        self.faults = [f for f in scn.faults if f.station == station_id]
        self._bias = [f for f in scn.faults if f.kind == "range_bias"]
        self._air: dict[int, AirChannel] = {}

    @property
    def active(self) -> bool:
        return bool(self.scn.faults or self.scn.links)

    def clock(self, clock):
        return with_clock_faults(clock, self.faults, self.id)

    def fix(self, pos0_m, cov0_m2, sigma0_m: float):
        """A ``bad_fix``: the coarse fix is off by ``offset_m`` while claiming ``sigma0_m``."""
        for f in self.faults:
            if f.kind == "bad_fix" and pos0_m is not None:
                free = np.diag(cov0_m2) > 0
                pos0_m = np.asarray(pos0_m, float) + np.asarray(f.offset_m) * free
                s0 = sigma0_m if f.sigma0_m is None else f.sigma0_m
                cov0_m2 = np.diag(free * s0**2).astype(float)
        return pos0_m, cov0_m2

    def outgoing(self, msg: dict, t_true_s: float) -> dict:
        """A ``liar`` puts an offset position in its nav broadcasts and range answers."""
        if msg.get("kind") not in LIE_KINDS:
            return msg
        for f in self.faults:
            if f.kind == "liar" and t_true_s >= f.from_s:
                msg = dict(msg)
                msg["pos_m"] = (np.asarray(msg["pos_m"], float) + np.asarray(f.offset_m)).tolist()
        return msg

    def _channel(self, air: AirChannel, tx_id: int) -> tuple[AirChannel, float]:
        """The receiver's air channel for the link from ``tx_id`` and that link's constant bias."""
        over = [o for o in self.scn.links if o.applies(tx_id, self.id)]
        if not over:
            return air, 0.0
        ch = self._air.get(tx_id)
        params = air.params
        bias = 0.0
        for o in over:  # later entries win
            params = replace(params, **{k: getattr(o, k) for k in ("nlos_prob", "nlos_bias_m", "loss_prob")
                                        if getattr(o, k) is not None})
            bias += o.bias_m
        if ch is None or ch.rng is not air.rng:
            ch = self._air[tx_id] = AirChannel(params, air.rng, air.key)  # same draws as the receiver's channel
        return ch, bias

    def arrival_local_s(self, air: AirChannel, tx_id: int, tx_pos_m, t_tx_true_s: float, rx_pos_m, rx_clock):
        """Like ``AirChannel.arrival_local_s`` with the link's overrides, constant bias and antenna
        faults (``range_bias``: each leg to or from the station is delayed by ``bias_m / c``)."""
        if not self.active:
            return air.arrival_local_s(tx_pos_m, t_tx_true_s, rx_pos_m, rx_clock, tx_id)
        ch, bias_m = self._channel(air, tx_id)
        for f in self._bias:
            if f.station in (tx_id, self.id) and t_tx_true_s >= f.from_s:
                bias_m += f.bias_m
        t_local = ch.arrival_local_s(tx_pos_m, t_tx_true_s, rx_pos_m, rx_clock, tx_id)
        if t_local is None or bias_m == 0.0:
            return t_local
        # a two-way range is c (t_rx - t_tx - turnaround) / 2: each leg carries bias_m / c
        return rx_clock.to_local(rx_clock.to_true(t_local) + bias_m / SPEED_OF_LIGHT_M_S)
