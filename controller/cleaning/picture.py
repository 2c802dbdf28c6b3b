"""A frozen tower camera, told from a still pond: the same picture frame after frame while the
robot is driving.

An encoder or a relay that froze sends its last picture again and again, and each copy arrives as
a new frame: the cleaner steered on it for 10 m, "tracking" at a pose it had left. A still pond
sends the same picture too (a calm night, a camera with temporal noise reduction, the simulator
with noise 0) — but then nothing moves, and the robot stands: its pictures are not frozen, and
dropping them (the camera driver did so for a day) locked a docked cleaner in ``fault``. Only a
robot under thrust must change what the camera sees: the same picture for ``hold_s`` farm seconds
while it drives is frozen, and no fix is taken from it until the picture changes.
"""
from __future__ import annotations

import numpy as np

HOLD_S = 1.0


class FrozenPicture:
    def __init__(self, hold_s: float = HOLD_S):
        self.hold_s = hold_s
        self.frozen = False
        self._last = None
        self._since: float | None = None      # farm time the same picture came first while driving

    def usable(self, t: float, image, driving: bool) -> bool:
        """Whether a fix may be taken from ``image`` (arrived at farm time ``t``); ``driving``:
        thrust was commanded since the last stop."""
        same = self._last is not None and _same(self._last, image)
        self._last = image
        if not same:
            self.frozen, self._since = False, None
            return True
        if self.frozen:
            return False
        if not driving:
            self._since = None
            return True
        if self._since is None:
            self._since = t
        if t - self._since >= self.hold_s:
            self.frozen = True
            return False
        return True


def _same(a, b) -> bool:
    if getattr(a, "shape", None) != getattr(b, "shape", None):
        return False
    return bool(np.array_equal(a, b))
