"""The search window of a tracking localiser: which modules a frame runs, and how the window follows the decisions.

A robot knows roughly where it is: a frame need not pay for the whole route. :class:`SearchWindow` says which
modules of an ensemble lie around the last accepted place (``modules``) and where the window goes after each
decision (``follow``); :class:`~vprsnn_export.runtime.localize.Localizer` runs those modules alone (their WTA) and
decides among their places (:meth:`~.scoring.Readout.wprob` over those places).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vprsnn_export.errors import InvalidValueError

#: Frames in a row without an accepted decision before the whole route runs again (``--patience``).
DEFAULT_PATIENCE = 3


@dataclass(frozen=True)
class SearchWindow:
    """Localise within ``places`` reference places around the last confident place: only the modules whose places lie in
    the window run (one WTA over them) and the frame is decided among their places; after ``patience`` frames in a row
    without an accepted decision the next frame runs the whole route (a global re-localisation), as does the first.
    With ``near`` (``--follow-within``), an unaccepted window decision within ``near`` places of where the window
    expected it (``c_j + v_j``) moves the window there and is no miss: the robot is taken to be on track. With
    ``lost_after`` (``--lost-after``), after that many window frames in a row without an accepted decision, followed
    ones included, the robot is lost (:meth:`lost`): the readout forgets its recent frames (they are the lost
    window's evidence, and they outvote a global frame in the k-frame aggregate) and every frame runs the whole
    route until one is accepted.

    .. math:: c_{j+1} = \\begin{cases} \\hat l_j & \\text{accepted}_j \\text{ or } |\\hat l_j - (c_j + v_j)|
              \\le \\text{near} \\\\ c_j + v_j & \\text{otherwise (a miss)} \\end{cases}, \\quad W_j = [\\,b, b + w), \\; b = \\min(\\max(\\lfloor c_j \\rceil -
              \\lfloor w / 2 \\rfloor, 0), L - w), \\quad \\text{run} = \\{m : \\text{region}_m \\cap W_j \\ne
              \\emptyset\\}
    """

    places: int
    patience: int = DEFAULT_PATIENCE
    near: int | None = None
    lost_after: int | None = None

    def __post_init__(self) -> None:
        for name, value in (
            ("search window", self.places),
            ("patience", self.patience),
            ("near", 1 if self.near is None else self.near),
            ("lost after", 1 if self.lost_after is None else self.lost_after),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InvalidValueError(f"{name} must be a whole number of frames or places >= 1, got {value!r:.40}")

    def follow(
        self, centre: float | None, misses: int, place: int | None, accepted: bool, velocity: float, waited: int = 0
    ) -> tuple[float | None, int, int]:
        """The next frame's (centre, misses, waited) after a frame decided at place index ``place`` (None: no place):
        ``centre`` None, a global frame, puts the window at its place (None: global again), and when it was not
        accepted one more miss looks at the whole route again; a window frame moves it to an accepted place, else
        ``velocity`` places on (or, within ``near`` of ``centre + velocity``, to its place without a miss), and after
        ``patience`` misses in a row, or ``lost_after`` window frames in a row without an accepted decision
        (``waited``), the next frame is global (centre None)."""
        if centre is None:
            if not accepted and self.lost(waited):
                return None, misses, waited  # lost: global until a decision is accepted
            return (None if place is None else float(place)), 0 if accepted else self.patience - 1, 0
        if accepted and place is not None:
            return float(place), 0, 0
        lost = self.lost(waited + 1)
        if self.near is not None and place is not None and abs(place - (centre + velocity)) <= self.near:
            return (None if lost else float(place)), misses, waited + 1  # on track: the window follows, no miss
        return (None if lost or misses + 1 >= self.patience else centre + velocity), misses + 1, waited + 1

    def lost(self, waited: int) -> bool:
        """Whether ``waited`` window frames in a row without an accepted decision make the robot lost (``lost_after``)."""
        return self.lost_after is not None and waited >= self.lost_after

    def modules(self, centre: float, regions: np.ndarray) -> tuple[int, int]:
        """[first, last) modules whose regions meet the window around ``centre`` (a reference place index)."""
        n_places = int(regions[-1, 1])
        start = min(max(int(round(centre)) - self.places // 2, 0), max(n_places - self.places, 0))
        stop = min(start + self.places, n_places)
        first = int(np.searchsorted(regions[:, 1], start, side="right"))
        return first, int(np.searchsorted(regions[:, 0], stop - 1, side="right"))
