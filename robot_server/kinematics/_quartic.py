"""Real roots of a trigonometric quadratic, vectorised: the one step of closed-form IK that is not
straight-line arithmetic (the general position case, docs in :mod:`.ik`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["trig_quadratic_roots"]

Array = NDArray[np.float64]

#: accepted |F| (m^2) at a polished root
QUARTIC_TOL = 1e-13
# tan-half-angle sample points and the inverse Vandermonde that turns samples into coefficients
_T_SAMPLES = (-2.0, -1.0, 0.0, 1.0, 2.0)
_VANDER_INV = np.linalg.inv(np.vander(np.array(_T_SAMPLES), 5))
_SHIFTS = (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi)


def trig_quadratic_roots(k0: Array, k1: Array, k2: Array, k3: Array, k4: Array, k5: Array) -> tuple[Any, ...]:
    """Roots q of ``F(q) = k0 + k1 c + k2 s + k3 c^2 + k4 s^2 + k5 c s = 0`` (c, s = cos q, sin q)
    for N coefficient sets at once: ``(q_1..q_4, valid_1..valid_4, double_1..double_4)``.

    The substitution ``q = beta + 2 atan(t)`` makes F a quartic in t; beta is chosen per row so
    that t = infinity is not a root. Roots come from the companion matrices' eigenvalues and are
    polished by Newton steps on F itself; a root is valid if nearly real and F vanishes there.
    """

    def f(q: Any) -> Any:
        c, s = np.cos(q), np.sin(q)
        return k0 + k1 * c + k2 * s + k3 * c * c + k4 * s * s + k5 * c * s

    def df(q: Any) -> Any:
        c, s = np.cos(q), np.sin(q)
        return -k1 * s + k2 * c + 2.0 * (k4 - k3) * c * s + k5 * (c * c - s * s)

    n = k0.shape[0]
    at_infinity = np.abs(np.stack([f(np.full(n, b + math.pi)) for b in _SHIFTS]))
    beta = np.array(_SHIFTS)[np.argmax(at_infinity, axis=0)]
    samples = np.stack([(1.0 + t * t) ** 2 * f(beta + 2.0 * math.atan(t)) for t in _T_SAMPLES], axis=1)
    coef = samples @ _VANDER_INV.T  # (N, 5), highest power first
    lead = coef[:, 0:1]
    companion = np.zeros((n, 4, 4))
    companion[:, 0, :] = -coef[:, 1:] / np.where(lead == 0.0, 1e-300, lead)
    companion[:, 1, 0] = companion[:, 2, 1] = companion[:, 3, 2] = 1.0
    roots = np.linalg.eigvals(companion)
    angles, valid, double = [], [], []
    for j in range(4):
        t = roots[:, j]
        q = beta + 2.0 * np.arctan(t.real)
        for _ in range(4):
            d = df(q)
            q = q - np.where(np.abs(d) > 1e-14, f(q) / np.where(d == 0.0, 1.0, d), 0.0)
        angles.append(q)
        valid.append((np.abs(t.imag) <= 1e-6 * (1.0 + np.abs(t))) & (np.abs(f(q)) <= QUARTIC_TOL))
        double.append(np.abs(df(q)) < 1e-7)
    return (*angles, *valid, *double)
