"""State layout of the radio filters: named blocks instead of column numbers.

``pr``: ``[p (3), v (3), b (, bdot)]`` with ``b = c * dtau`` the receiver clock offset in metres and
``bdot`` its rate (``drift=True``); ``tdoa``: ``[p (3), v (3)]``. Clock-bias states of the stations
(:mod:`.biases`) follow the ``n`` base states.
"""

from __future__ import annotations

from dataclasses import dataclass

# the named blocks of the base state (every layout starts with position and velocity)
POS = slice(0, 3)  # position, m
VEL = slice(3, 6)  # velocity, m/s
Z = 2  # the height coordinate of the position (the floor's constraint)
CLOCK = 6  # clock offset b, m (pr)
CLOCK_RATE = 7  # clock rate bdot, m/s (pr with drift)


@dataclass(frozen=True)
class StateLayout:
    """Which measurement model and which clock states a filter carries."""

    kind: str  # "pr" or "tdoa"
    drift: bool = False  # pr only: carry the clock rate state

    @property
    def n(self) -> int:
        """Number of base states (without clock biases)."""
        if self.kind == "tdoa":
            return 6
        return 8 if self.drift else 7

    def __post_init__(self) -> None:
        if self.kind not in ("pr", "tdoa"):
            raise ValueError(f"unknown measurement model {self.kind!r} (pr or tdoa)")
        if self.kind == "tdoa" and self.drift:
            raise ValueError("the TDOA state has no clock")

    # -- named blocks
    pos = POS
    vel = VEL

    @property
    def has_clock(self) -> bool:
        return self.kind == "pr"

    @property
    def clock(self) -> int | None:
        """Index of the clock offset ``b`` (m); None without a clock (TDOA)."""
        return CLOCK if self.kind == "pr" else None

    @property
    def clock_rate(self) -> int | None:
        """Index of the clock rate ``bdot`` (m/s); None without it."""
        return CLOCK_RATE if self.drift else None

    @property
    def pos_clock(self) -> list[int]:
        """Columns of the position and the clock offset: the snapshot (LSQ) unknowns ``[x y z (b)]``."""
        return [0, 1, 2] + ([CLOCK] if self.kind == "pr" else [])

    def biases(self, nb: int) -> slice:
        """Columns of ``nb`` station clock-bias states after the base states."""
        return slice(self.n, self.n + nb)
