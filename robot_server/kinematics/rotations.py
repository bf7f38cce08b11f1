"""Rotations as unit quaternions: conversion to and from matrices, slerp, the angle between two.

Quaternions are ``(w, x, y, z)`` here (Hamilton convention), with ``w >= 0`` where a function
chooses the sign; the wire and ROS write them ``(x, y, z, w)``, converted at the edges. The numpy
functions take batches; :func:`quaternion_of` is the scalar version the control loop calls every
interpolation period (plain floats, about a microsecond).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..arrays import Array

__all__ = ["rotation_to_quaternion", "quaternion_to_rotation", "slerp", "quaternion_angle", "quaternion_of"]


def quaternion_of(rows: Sequence[float]) -> tuple[float, float, float, float]:
    """The unit quaternion ``(w, x, y, z)`` (w >= 0) of a rotation given by its 9 entries, row
    by row, as floats."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rows
    trace = r00 + r11 + r22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        w, x, y, z = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 >= r11 and r00 >= r22:
        s = 2.0 * math.sqrt(max(1.0 + r00 - r11 - r22, 0.0))
        w, x, y, z = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 >= r22:
        s = 2.0 * math.sqrt(max(1.0 + r11 - r00 - r22, 0.0))
        w, x, y, z = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + r22 - r00 - r11, 0.0))
        w, x, y, z = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return w / n, x / n, y / n, z / n


def rotation_to_quaternion(r: ArrayLike) -> Array:
    """Unit quaternion ``(w, x, y, z)`` (w >= 0) of a rotation matrix (3x3, or the top left of a 4x4)."""
    m = np.asarray(r, dtype=float)[:3, :3]
    return np.array(quaternion_of(m.reshape(9).tolist()))


def quaternion_to_rotation(q: ArrayLike) -> Array:
    """Rotation matrices of unit quaternions ``(..., 4)`` -> ``(..., 3, 3)``."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def slerp(q0: ArrayLike, q1: ArrayLike, u: ArrayLike) -> Array:
    """Spherical linear interpolation of unit quaternions at fractions ``u`` (the shorter way):
    ``(4,)`` for a scalar ``u``, ``(m, 4)`` for m fractions."""
    a = np.asarray(q0, dtype=float)
    b = np.asarray(q1, dtype=float)
    f = np.asarray(u, dtype=float)[..., None]
    dot = float(np.dot(a, b))
    if dot < 0.0:
        b, dot = -b, -dot
    if dot > 1.0 - 1e-12:
        out = a + f * (b - a)
    else:
        theta = math.acos(dot)
        out = (np.sin((1.0 - f) * theta) * a + np.sin(f * theta) * b) / math.sin(theta)
    norm: Array = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return norm


def quaternion_angle(q0: ArrayLike, q1: ArrayLike) -> float:
    """The angle (rad, 0..pi) of the rotation from ``q0`` to ``q1``, accurate near 0 (from the
    relative rotation's vector part, not the acos of a dot product)."""
    a = np.asarray(q0, dtype=float)
    b = np.asarray(q1, dtype=float)
    w = float(np.dot(a, b))
    vector = a[0] * b[1:] - b[0] * a[1:] - np.cross(a[1:], b[1:])
    return 2.0 * math.atan2(float(np.linalg.norm(vector)), abs(w))
