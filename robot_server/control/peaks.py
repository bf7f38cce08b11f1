"""Peak ratios of the rest-to-rest shapes: the one home of these numbers, for the controller's
policies and for planners that time points for them.

A rest-to-rest segment covering ``D`` in ``T`` seconds (zero velocity at both ends; the quintic
zero acceleration too) peaks at ``ratio x D / T`` in speed and ``ratio x D / T^2`` in
acceleration, whatever ``D`` and ``T``. With ``u = t / T`` and ``p = p0 + D s(u)``:

* cubic (:func:`.segments.cubic`), ``s = 3 u^2 - 2 u^3``: ``s' = 6 u (1 - u)`` peaks at
  ``u = 1/2`` (1.5); ``s'' = 6 - 12 u`` is largest at the ends (6, where it steps from 0);
* quintic (:func:`.segments.quintic`), ``s = 10 u^3 - 15 u^4 + 6 u^5``: ``s' = 30 u^2 (1 - u)^2``
  peaks at ``u = 1/2`` (30 / 16 = 1.875); ``s'' = 60 u (1 - u) (1 - 2 u)`` peaks at
  ``u = (3 -+ sqrt 3) / 6`` (10 / sqrt 3 = 5.7735...).

So the shortest segment time within a speed ``v`` and an acceleration ``a`` is
``max(PEAK_VELOCITY x D / v, sqrt(PEAK_ACCELERATION x D / a))``: what the ``cubic`` and ``quintic``
policies compute when a point has no duration (:mod:`.policies`), and what a client needs to time
points for them (docs/reference/motion.md §4).
"""

from __future__ import annotations

import math

__all__ = [
    "CUBIC_PEAK_VELOCITY",
    "CUBIC_PEAK_ACCELERATION",
    "QUINTIC_PEAK_VELOCITY",
    "QUINTIC_PEAK_ACCELERATION",
]

#: the rest-to-rest cubic's peak speed over D / T
CUBIC_PEAK_VELOCITY = 1.5
#: the rest-to-rest cubic's peak acceleration over D / T^2 (at both ends)
CUBIC_PEAK_ACCELERATION = 6.0
#: the rest-to-rest quintic's peak speed over D / T (15 / 8)
QUINTIC_PEAK_VELOCITY = 1.875
#: the rest-to-rest quintic's peak acceleration over D / T^2 (10 / sqrt 3)
QUINTIC_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)
