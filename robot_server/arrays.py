"""The project's one float array alias: :data:`Array`, a numpy array of float64.

Joint values, poses, samples of a segment: every module of :mod:`robot_server` and :mod:`client`
that hands float arrays around names their type ``Array`` and imports it from here (:mod:`client`
and code outside the packages as ``robot_server.Array``), so the name means one thing throughout.
It loads numpy only.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["Array"]

#: a numpy array of float64, of any shape
Array = NDArray[np.float64]
