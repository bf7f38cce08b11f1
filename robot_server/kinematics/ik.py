"""Closed-form inverse kinematics for 6R arms whose last three axes intersect.

Derived from the model's geometry, not from one robot's numbers. At q = 0 each joint i is a line
(point ``o_i``, unit direction ``h_i``) in the base frame; the flange pose is the product of
rotations about those lines applied to the zero pose M (product of exponentials). When axes 4, 5
and 6 meet in one point c (a spherical wrist), the wrist centre ``p_w = T . M^-1 . c`` depends on
q1..q3 only (Pieper), and the problem splits in two:

**Position** (q1, q2, q3). Let ``v(q3) = y - o2`` where y is c turned about axis 3, and let o1, o2
be the feet of the common normal w of axes 1 and 2. Rotations about axis 1 keep the distance to o1
and the height along h1, which gives two equations in (q2, q3) with ``D = |p_w - o1|^2`` and
``H = h1 . (p_w - o1)``:

    2 (v.w) cos q2 + 2 (v.(w x h2)) sin q2 = D - |w|^2 - |v|^2                     (E1)
    (v.h1p) cos q2 + (v.(h1 x h2)) sin q2 = H - h1.w - (h1.h2)(h2.v)   h1p = h1 - (h1.h2) h2   (E2)

Every coefficient is linear in (cos q3, sin q3). Three cases, chosen from the model:

* axes 1 and 2 intersect (|w| = 0): E1 alone fixes q3 (two roots), then E2 gives two q2;
* axes 1 and 2 are parallel: E2 alone fixes q3, then E1 gives two q2;
* otherwise: eliminating q2 (the two equations are a rotation of the same 2-vector) leaves
  ``(E1rhs / 2|w|)^2 + (E2rhs / sin a12)^2 = |v|^2 - (h2.v)^2``, a quartic in tan(q3/2): up to four
  q3, each with one q2. Where h2.v varies with q3 only through ``X = |v|^2 - n0`` (always when
  axes 2 and 3 are parallel, as on most industrial arms with a shoulder offset) it is a quadratic
  in X instead, and each X gives two q3 ("offset"); only truly skew arms need the quartic.

q1 then turns the point reached by q2, q3 onto p_w (a rotation about one axis). **Orientation**
(q4, q5, q6): ``W = R3^T R2^T R1^T R M0^T = Rot(h4,q4) Rot(h5,q5) Rot(h6,q6)``; h4.W.h6 fixes q5
(two roots, the wrist flip), q4 turns Rot(h5,q5) h6 onto W h6, and q6 is what remains. Only
vectors are rotated, never matrices multiplied.

At most 4 x 2 = 8 solutions. Singular cases never give NaN: at the wrist singularity (axes 4 and 6
aligned) q4 is free and the seed's q4 is kept; at the shoulder singularity (wrist centre on axis 1)
q1 is free and the seed's q1 is kept; at the elbow singularity the two q3 branches merge. Each
solution carries flags saying which of these it is at.

The solver is written once for floats and traced per model into straight-line code with the
model's constants folded in (:mod:`._trace`); that code runs on floats for one pose and on numpy
arrays for a batch.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Iterable, Sequence
from enum import IntFlag
from typing import Generic, NamedTuple, TypeVar, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model import JointType, ModelError, RobotModel
from ._chain import chain
from ._ops import ARRAY_OPS, SCALAR_OPS, AnyArray, Ops, TrigRoot
from ._trace import TRACE_OPS, Flags, Generated, Real, Tracer, Truth, Var
from .fk import fk

__all__ = ["Singularity", "IKSolution", "Branch", "BatchSolutions", "ClosedFormIK", "NotApplicable", "closed_form"]

Matrix = NDArray[np.float64]
V = TypeVar("V")
#: a vector in traced code
Vec = tuple[Real, Real, Real]
#: a vector of the model's constants
FVec = tuple[float, float, float]
_TWO_PI = 2.0 * math.pi
_CHUNK = 4096

#: geometry tolerance (m, or dimensionless for directions) when classifying the model
_GEOMETRY_TOL = 1e-9
#: an acos argument this far past +-1 still counts as reachable (rounding), and is clamped
_REACH_TOL = 1e-9
#: below this |sin| / distance (m) a rotation angle is undetermined: the seed's value is used
_DEGENERATE = 1e-9


class NotApplicable(ModelError):
    """The model is not a 6R chain with intersecting last three axes; use numeric IK."""


class Singularity(IntFlag):
    NONE = 0
    WRIST = 1  # axes 4 and 6 aligned: only a combination of q4 and q6 is determined
    SHOULDER = 2  # wrist centre on axis 1: q1 undetermined
    ELBOW = 4  # elbow-up and elbow-down branches coincide


_FLAGS = [Singularity(i) for i in range(8)]


class IKSolution(NamedTuple):
    """One inverse-kinematics solution: joint values (rad) and the singularities it sits at."""

    q: tuple[float, ...]
    singular: Singularity = Singularity.NONE


class Branch(NamedTuple, Generic[V]):
    """One of the 8 branches of the generated solver (floats for one pose, arrays for a batch):
    the joint values before any 2 pi shift, whether the branch reaches the pose, and its
    :class:`Singularity` flags."""

    q: tuple[float | V, ...]
    valid: bool | V
    flags: int | V


class BatchSolutions(NamedTuple):
    """:meth:`ClosedFormIK.solve_batch`: for N poses, ``q (N, 8, 6)`` (NaN in invalid slots),
    ``valid (N, 8)`` and the :class:`Singularity` flags ``(N, 8)``."""

    q: NDArray[np.float64]
    valid: NDArray[np.bool_]
    flags: NDArray[np.int64]


def _vec(values: Sequence[float] | NDArray[np.float64]) -> FVec:
    return (float(values[0]), float(values[1]), float(values[2]))


@overload
def _dot(a: FVec, b: FVec) -> float: ...
@overload
def _dot(a: Vec, b: Vec) -> Real: ...
def _dot(a: Vec, b: Vec) -> Real:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@overload
def _cross(a: FVec, b: FVec) -> FVec: ...
@overload
def _cross(a: Vec, b: Vec) -> Vec: ...
def _cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@overload
def _sub(a: FVec, b: FVec) -> FVec: ...
@overload
def _sub(a: Vec, b: Vec) -> Vec: ...
def _sub(a: Vec, b: Vec) -> Vec:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@overload
def _scaled(v: FVec, k: float) -> FVec: ...
@overload
def _scaled(v: Vec, k: Real) -> Vec: ...
def _scaled(v: Vec, k: Real) -> Vec:
    return (v[0] * k, v[1] * k, v[2] * k)


def _rotate(h: Vec, c: Real, s: Real, v: Vec) -> Vec:
    """v turned about the unit direction h by the angle with cosine c and sine s (Rodrigues)."""
    k = _dot(h, v) * (1.0 - c)
    x = _cross(h, v)
    return (v[0] * c + x[0] * s + h[0] * k, v[1] * c + x[1] * s + h[1] * k, v[2] * c + x[2] * s + h[2] * k)


def _vec3(values: Iterable[Real]) -> Vec:
    x, y, z = values
    return (x, y, z)


def _lin(v0: Vec, vc: Vec, vs: Vec, c: Real, s: Real) -> Vec:
    return (v0[0] + vc[0] * c + vs[0] * s, v0[1] + vc[1] * c + vs[1] * s, v0[2] + vc[2] * c + vs[2] * s)


def _trig_roots(ops: Ops[Var], p0: Real, pc: Real, ps: Real) -> tuple[Real, Real, Truth, Truth]:
    """Both roots of ``p0 + pc cos q + ps sin q = 0``: (q_a, q_b, reachable, merged)."""
    r = ops.sqrt(pc * pc + ps * ps)
    safe = ops.where(r > 1e-300, r, 1.0)
    arg = -p0 / safe
    reachable = (abs(arg) <= 1.0 + _REACH_TOL) & (r > 1e-300)
    base = ops.atan2(ps, pc)
    delta = ops.acos(arg)
    merged = abs(arg) >= 1.0 - 1e-12
    return base + delta, base - delta, reachable, merged


def _turn_angle(ops: Ops[Var], h: Vec, p: Vec, t: Vec, fallback: Real) -> tuple[Real, Truth]:
    """The angle about h that turns p onto t (their components across h); ``fallback`` when p has
    no such component (the angle is free): (angle, degenerate)."""
    pp = _sub(p, _scaled(h, _dot(h, p)))
    tt = _sub(t, _scaled(h, _dot(h, t)))
    sin_part = _dot(h, _cross(pp, tt))
    cos_part = _dot(pp, tt)
    degenerate = _dot(pp, pp) < _DEGENERATE * _DEGENERATE
    return ops.where(degenerate, fallback, ops.atan2(sin_part, cos_part)), degenerate


class ClosedFormIK:
    """Closed-form IK of one model (build once; see :func:`closed_form`)."""

    def __init__(self, model: RobotModel) -> None:
        if model.dof != 6 or any(j.type is not JointType.REVOLUTE for j in model.joints):
            raise NotApplicable(f"{model.name}: closed-form IK needs 6 revolute joints")
        self.model = model
        axes, points = _axis_lines(model)
        self.h = [_vec(a) for a in axes]
        o = [_vec(p) for p in points]
        centre = _wrist_centre(model.name, axes[3:], points[3:])
        zero = fk(model, [0.0] * 6)
        # the flange orientation at q = 0, and the wrist centre's offset from the flange (base axes)
        self.r0 = zero[:3, :3].copy()
        self.c_flange = _vec(self.r0 @ np.linalg.solve(zero, np.append(centre, 1.0))[:3])
        # o1, o2: feet of the common normal of axes 1 and 2
        o1, o2 = _common_normal_feet(np.array(o[0]), axes[0], np.array(o[1]), axes[1])
        w = o2 - o1
        self.a = float(np.linalg.norm(w))
        k = np.cross(axes[0], axes[1])
        self.sigma = float(np.linalg.norm(k))
        if self.a < _GEOMETRY_TOL and self.sigma < _GEOMETRY_TOL:
            raise NotApplicable(f"{model.name}: axes 1 and 2 coincide")
        h1, h2, h3 = axes[0], axes[1], axes[2]
        u = centre - points[2]
        self.o1 = _vec(o1)
        self.o2 = _vec(o2)
        self.w = _vec(w)
        self.g = _vec(np.cross(w, h2))
        self.k = _vec(k)
        self.h1p = _vec(h1 - np.dot(h1, h2) * h2)
        self.h12 = float(np.dot(h1, h2))
        self.v0 = _vec(points[2] - o2 + np.dot(h3, u) * h3)
        self.vc = _vec(u - np.dot(h3, u) * h3)
        self.vs = _vec(np.cross(h3, u))
        if np.linalg.norm(self.vc) < _GEOMETRY_TOL:
            raise NotApplicable(f"{model.name}: the wrist centre lies on axis 3")
        self.ww = float(np.dot(w, w))
        self.h1w = float(np.dot(h1, w))
        # the unit vector across h6 used to read q6
        n6 = np.cross(axes[5], [1.0, 0.0, 0.0])
        if np.linalg.norm(n6) < 0.1:
            n6 = np.cross(axes[5], [0.0, 1.0, 0.0])
        self.n6 = _vec(n6 / np.linalg.norm(n6))
        # |v|^2 = n0 + X and h2.v = m0 + (m1 c3 + m2 s3), where X = n1 c3 + n2 s3
        v0, vc, vs = self.v0, self.vc, self.vs
        self.n0 = _dot(v0, v0) + _dot(vc, vc)
        self.n1, self.n2 = 2.0 * _dot(v0, vc), 2.0 * _dot(v0, vs)
        self.m0, self.m1, self.m2 = _dot(self.h[1], v0), _dot(self.h[1], vc), _dot(self.h[1], vs)
        n_size = self.n_size = math.hypot(self.n1, self.n2)
        self.ratio = 0.0
        if self.a < _GEOMETRY_TOL:
            self.case = "intersecting"
        elif self.sigma < _GEOMETRY_TOL:
            self.case = "parallel"
        elif n_size > _GEOMETRY_TOL and abs(self.m1 * self.n2 - self.m2 * self.n1) < _GEOMETRY_TOL * n_size:
            # h2.v moves with X alone (m = ratio n; always when axes 2 and 3 are parallel, as on most
            # industrial arms): the quartic is a quadratic in X
            self.case = "offset"
            self.ratio = (self.m1 * self.n1 + self.m2 * self.n2) / (n_size * n_size)
        else:
            self.case = "general"
        h4, h5, h6 = self.h[3], self.h[4], self.h[5]
        h56 = _dot(h5, h6)
        # q5 equation constants: h4.W.h6 = wrist_const + alpha cos q5 + beta sin q5
        self.wrist_alpha = _dot(h4, h6) - h56 * _dot(h4, h5)
        self.wrist_beta = _dot(h4, _cross(h5, h6))
        self.wrist_const = h56 * _dot(h4, h5)
        self.p6 = (_scaled(h5, h56), _sub(h6, _scaled(h5, h56)), _cross(h5, h6))
        self.h23_parallel = bool(np.allclose(axes[1], axes[2], rtol=0.0, atol=1e-12))
        self.limits = tuple(zip(model.lower.tolist(), model.upper.tolist(), strict=True))
        self._solver, self._batch_solver = self._trace()

    def _trace(self) -> tuple[Generated[tuple[Branch[float], ...]], Generated[tuple[Branch[AnyArray], ...]]]:
        """The generated solver ``f(r00, ..., r22, px, py, pz, s0, ..., s5, ops)`` (rotation,
        position, seed) for floats and for numpy columns: the 8 :class:`Branch`."""
        tracer = Tracer()
        names = [f"r{i}{j}" for i in range(3) for j in range(3)] + ["px", "py", "pz"] + [f"s{i}" for i in range(6)]
        var = {name: tracer.input(name) for name in names}
        # rt = R . M0^T, with the model's M0 folded in
        r0 = self.r0.tolist()
        rt = [[sum(var[f"r{i}{k}"] * r0[j][k] for k in range(3)) for j in range(3)] for i in range(3)]
        p = (var["px"], var["py"], var["pz"])
        seed = [var[f"s{i}"] for i in range(6)]
        outputs = tuple(self._branches(TRACE_OPS, rt, p, seed))
        label = f"closed-form IK of {self.model.name}"
        return (
            tracer.compile("closed_form_ik", names, outputs, label),
            tracer.compile("closed_form_ik_batch", names, outputs, label, batch=True),
        )

    # -- the solver, traced ----------------------------------------------------------------------

    def _branches(self, ops: Ops[Var], rt: Sequence[Sequence[Real]], p: Vec, seed: Sequence[Real]) -> list[Branch[Var]]:
        """All 8 branches."""
        h1, h2, h3, h4, h5, h6 = self.h
        cf = self.c_flange
        # rt = R . M0^T. The wrist centre p + R c_flange = p + rt (M0 c_flange), and W h6, W n6
        # before q1..q3 are undone
        pw = _vec3(p[i] + rt[i][0] * cf[0] + rt[i][1] * cf[1] + rt[i][2] * cf[2] for i in range(3))
        rel = _sub(pw, self.o1)
        dd = _dot(rel, rel)
        hh = _dot(h1, rel)
        t_h6 = _vec3(rt[i][0] * h6[0] + rt[i][1] * h6[1] + rt[i][2] * h6[2] for i in range(3))
        n6 = self.n6
        t_n6 = _vec3(rt[i][0] * n6[0] + rt[i][1] * n6[1] + rt[i][2] * n6[2] for i in range(3))
        positions = self._positions(ops, dd, hh, rel, seed)
        out = []
        for q1, q2, q3, valid, flags in positions:
            # undo q1, q2, q3 (rotate by minus the angles, innermost last)
            a_h6, a_n6 = t_h6, t_n6
            # rotations compose by direction only: with h3 = h2 (parallel axes, as on most arms)
            # the last two are one turn by q2 + q3
            turns: tuple[tuple[Vec, Real], ...] = (
                ((h1, q1), (h2, q2 + q3)) if self.h23_parallel else ((h1, q1), (h2, q2), (h3, q3))
            )
            for h, q in turns:
                c, s = ops.cos(q), -ops.sin(q)
                a_h6 = _rotate(h, c, s, a_h6)
                a_n6 = _rotate(h, c, s, a_n6)
            # q5 from h4 . W h6 = h4 . Rot(h5, q5) h6
            gamma = _dot(h4, a_h6) - self.wrist_const
            q5a, q5b, ok5, merged5 = _trig_roots(ops, -gamma, self.wrist_alpha, self.wrist_beta)
            for q5 in (q5a, q5b):
                c5, s5 = ops.cos(q5), ops.sin(q5)
                p6 = _lin(*self.p6, c5, s5)  # Rot(h5, q5) h6
                q4, wrist = _turn_angle(ops, h4, p6, a_h6, seed[3])
                c4, s4 = ops.cos(q4), ops.sin(q4)
                # Rot(h6, q6) = (Rot4 Rot5)^T W: read it on n6
                m = _rotate(h5, c5, -s5, _rotate(h4, c4, -s4, a_n6))
                q6 = ops.atan2(_dot(h6, _cross(self.n6, m)), _dot(self.n6, m))
                at_wrist = ops.flag(wrist | merged5, int(Singularity.WRIST))
                out.append(Branch((q1, q2, q3, q4, q5, q6), valid & ok5, flags | at_wrist))
        return out

    def _positions(
        self, ops: Ops[Var], dd: Real, hh: Real, rel: Vec, seed: Sequence[Real]
    ) -> list[tuple[Real, Real, Real, Truth, Flags]]:
        """(q1, q2, q3, valid, flags) for each position branch."""
        h1, h2 = self.h[0], self.h[1]
        v0, vc, vs, w = self.v0, self.vc, self.vs, self.w
        n0, n1, n2, m0, m1, m2 = self.n0, self.n1, self.n2, self.m0, self.m1, self.m2
        # E1 rhs = C1 = e0 - n1 c3 - n2 s3;  E2 rhs = C2 = f0 - h12 (m1 c3 + m2 s3)
        e0 = dd - self.ww - n0
        f0 = hh - self.h1w - self.h12 * m0
        triples: list[tuple[Real, Real, Truth, Flags]] = []  # (q3, q2, valid, flags)
        if self.case in ("intersecting", "parallel"):
            if self.case == "intersecting":
                q3a, q3b, ok3, merged = _trig_roots(ops, e0, -n1, -n2)
            else:
                q3a, q3b, ok3, merged = _trig_roots(ops, f0, -self.h12 * m1, -self.h12 * m2)
            elbow = ops.flag(merged, int(Singularity.ELBOW))
            for q3 in (q3a, q3b):
                c3, s3 = ops.cos(q3), ops.sin(q3)
                v = _lin(v0, vc, vs, c3, s3)
                if self.case == "intersecting":  # E2: A2 c2 + B2 s2 = C2
                    a2, b2, rhs = _dot(v, self.h1p), _dot(v, self.k), f0 - self.h12 * (m1 * c3 + m2 * s3)
                else:  # E1
                    a2, b2, rhs = 2.0 * _dot(v, w), 2.0 * _dot(v, self.g), e0 - n1 * c3 - n2 * s3
                q2a, q2b, ok2, _ = _trig_roots(ops, -rhs, a2, b2)
                free = a2 * a2 + b2 * b2 < _DEGENERATE * _DEGENERATE
                for q2 in (q2a, q2b):
                    q2 = ops.where(free, seed[1], q2)
                    flags = elbow | ops.flag(free, int(Singularity.SHOULDER))
                    triples.append((q3, q2, ok3 & (ok2 | free), flags))
        else:
            roots = self._offset_roots(ops, e0, f0) if self.case == "offset" else self._quartic_roots(ops, e0, f0)
            for q3, ok3, double in roots:
                c3, s3 = ops.cos(q3), ops.sin(q3)
                v = _lin(v0, vc, vs, c3, s3)
                a1_, b1 = 2.0 * _dot(v, w), 2.0 * _dot(v, self.g)
                a2_, b2 = _dot(v, self.h1p), _dot(v, self.k)
                r1 = e0 - n1 * c3 - n2 * s3
                r2 = f0 - self.h12 * (m1 * c3 + m2 * s3)
                det = a1_ * b2 - a2_ * b1
                free = abs(det) < _DEGENERATE * _DEGENERATE
                safe = ops.where(free, 1.0, det)
                q2 = ops.where(free, seed[1], ops.atan2((a1_ * r2 - a2_ * r1) / safe, (r1 * b2 - r2 * b1) / safe))
                flags = ops.flag(double, int(Singularity.ELBOW)) | ops.flag(free, int(Singularity.SHOULDER))
                triples.append((q3, q2, ok3, flags))
        out = []
        for q3, q2, valid, flags in triples:
            c3, s3 = ops.cos(q3), ops.sin(q3)
            v = _lin(v0, vc, vs, c3, s3)
            x = _sub(_rotate(h2, ops.cos(q2), ops.sin(q2), v), (-w[0], -w[1], -w[2]))  # x - o1 = w + R2 v
            q1, shoulder = _turn_angle(ops, h1, x, rel, seed[0])
            out.append((q1, q2, q3, valid, flags | ops.flag(shoulder, int(Singularity.SHOULDER))))
        return out

    def _offset_roots(self, ops: Ops[Var], e0: Real, f0: Real) -> tuple[TrigRoot[Var], ...]:
        """q3 where axes 1 and 2 are skew and h2.v = m0 + ratio X: with L1 = (e0 - X) / 2|w| and
        L2 = (f0 - h12 ratio X) / sin a12, the elimination gives ``A X^2 + B X + C = 0``; each real
        X gives two q3 from ``n1 c3 + n2 s3 = X``. Returned like :func:`._quartic.trig_quadratic_roots`
        (four q3, each valid or not, at the elbow singularity or not).

        The elbow is singular where the two q3 of one X meet (|X| = |n|: the arm stretched or folded),
        flagged as in the other cases by :func:`_trig_roots` (|X| / |n| within 1e-12 of 1, i.e. q3
        within about 1.4e-6 rad of it). Not by the slope of F at the computed root: there q3 is known
        only to about the square root of the rounding (|X| / |n| one ulp short of 1 puts each root
        1.5e-8 rad off), so that slope is F'' = |2 A X + B| |n| (about 13 m^2 on the KUKA) times
        1.5e-8 or more, and whether it fell under a fixed bound depended on the last bit of X. Where
        instead the two X meet (disc = 0: the two shoulder sides, e.g. the wrist centre on axis 1)
        the elbow branches stay apart: not an elbow singularity."""
        lam, h12, a2, s2 = self.ratio, self.h12, 4.0 * self.a * self.a, self.sigma * self.sigma
        quad = 1.0 / a2 + h12 * h12 * lam * lam / s2 + lam * lam
        lin = -2.0 * e0 / a2 - 2.0 * h12 * lam * f0 / s2 - 1.0 + 2.0 * self.m0 * lam
        const = e0 * e0 / a2 + f0 * f0 / s2 - self.n0 + self.m0 * self.m0
        disc = lin * lin - 4.0 * quad * const
        # a double X is still real if it misses by rounding (X within _REACH_TOL |n| of real)
        real = disc >= -4.0 * quad * quad * (_REACH_TOL * self.n_size) ** 2
        root = ops.sqrt(disc)
        roots: list[TrigRoot[Var]] = []
        for x in ((-lin + root) / (2.0 * quad), (-lin - root) / (2.0 * quad)):
            q3a, q3b, ok3, merged = _trig_roots(ops, -x, self.n1, self.n2)
            for q3 in (q3a, q3b):
                valid = real & ok3
                roots.append(TrigRoot(q3, valid, valid & merged))
        return tuple(roots)

    def _quartic_roots(self, ops: Ops[Var], e0: Real, f0: Real) -> tuple[TrigRoot[Var], ...]:
        """q3 in the general case: the roots of the quartic (see the module doc)."""
        n0, n1, n2, m0, m1, m2 = self.n0, self.n1, self.n2, self.m0, self.m1, self.m2
        l1 = [x / (2.0 * self.a) for x in (e0, -n1, -n2)]
        l2 = [x / self.sigma for x in (f0, -self.h12 * m1, -self.h12 * m2)]
        # F = L1^2 + L2^2 - |v|^2 + (h2.v)^2, as k0 + k1 c + k2 s + k3 c^2 + k4 s^2 + k5 cs
        kk: list[Real] = [-n0, -n1, -n2, 0.0, 0.0, 0.0]
        for a0, a1, a2 in (l1, l2, (m0, m1, m2)):
            kk[0] = kk[0] + a0 * a0
            kk[1] = kk[1] + 2.0 * a0 * a1
            kk[2] = kk[2] + 2.0 * a0 * a2
            kk[3] = kk[3] + a1 * a1
            kk[4] = kk[4] + a2 * a2
            kk[5] = kk[5] + 2.0 * a1 * a2
        return ops.quartic(*kk)

    # -- public API ------------------------------------------------------------------------------

    def solve_all(self, pose: ArrayLike, seed: ArrayLike | None = None) -> list[IKSolution]:
        """Every distinct solution within the joint limits (up to 8), each joint shifted by
        multiples of 2 pi to the value nearest the seed (or nearest 0) inside its limits."""
        t = np.asarray(pose, dtype=float)
        if t.shape != (4, 4):
            raise ValueError(f"a pose is a 4x4 homogeneous matrix, not shape {t.shape}")
        ref = (0.0,) * 6 if seed is None else tuple(np.asarray(seed, dtype=float).reshape(6).tolist())
        (r00, r01, r02, px), (r10, r11, r12, py), (r20, r21, r22, pz), _ = t.tolist()
        branches = self._solver(r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz, *ref, SCALAR_OPS)
        found: list[IKSolution] = []
        # branches coincide only at singularities, which are flagged: compare only then
        singular = any(branch.flags for branch in branches)
        for branch in branches:
            if not branch.valid:
                continue
            q = _shift_into_limits(branch.q, ref, self.limits)
            if q is None:
                continue
            if singular and any(max(abs(x - y) for x, y in zip(q, s.q, strict=True)) < 1e-9 for s in found):
                continue
            found.append(IKSolution(q, _FLAGS[int(branch.flags)]))
        return found

    def solve(self, pose: ArrayLike, seed: ArrayLike) -> IKSolution | None:
        """The solution nearest ``seed`` (Euclidean in joint space), or None if unreachable."""
        s = tuple(np.asarray(seed, dtype=float).reshape(6).tolist())
        solutions = self.solve_all(pose, s)
        if not solutions:
            return None
        return min(solutions, key=lambda sol: sum((a - b) ** 2 for a, b in zip(sol.q, s, strict=True)))

    def nearest(self, rotation: Sequence[float], position: Sequence[float], seed: Sequence[float]) -> IKSolution | None:
        """:meth:`solve` for a pose given as floats (the rotation's 9 entries row by row, the
        position) and a seed of 6 floats, without numpy's conversions: the form a control loop
        calls every interpolation period."""
        best: tuple[float, ...] | None = None
        flags, distance = 0, math.inf
        for branch in self._solver(*rotation, *position, *seed, SCALAR_OPS):
            if not branch.valid:
                continue
            q = _shift_into_limits(branch.q, seed, self.limits)
            if q is None:
                continue
            d = sum((a - b) ** 2 for a, b in zip(q, seed, strict=True))
            if d < distance:
                best, flags, distance = q, int(branch.flags), d
        return None if best is None else IKSolution(best, _FLAGS[flags])

    def solve_batch(self, poses: ArrayLike, seeds: ArrayLike | None = None, *, limits: bool = True) -> BatchSolutions:
        """N poses ``(N, 4, 4)`` -> solutions ``q (N, 8, 6)``, ``valid (N, 8)``, singularity
        ``flags (N, 8)``; no Python loop over N. Invalid slots (unreachable, outside the limits,
        or repeats of an earlier slot) hold NaN. With ``limits=False`` the joint limits are not
        applied: every joint is within pi of its seed, and a slot is invalid only where the
        branch does not reach the pose (or repeats another), so that a caller can tell a pose
        out of reach from one beyond a joint's limits."""
        t = np.asarray(poses, dtype=float)
        if t.ndim != 3 or t.shape[1:] != (4, 4):
            raise ValueError(f"solve_batch takes (N, 4, 4) poses, not shape {t.shape}")
        n = t.shape[0]
        ref = np.zeros((n, 6)) if seeds is None else np.broadcast_to(np.asarray(seeds, dtype=float), (n, 6))
        rt = np.ascontiguousarray(t[:, :3, :3].reshape(n, 9).T)
        p = np.ascontiguousarray(t[:, :3, 3].T)
        r = np.ascontiguousarray(ref.T)
        q = np.empty((n, 8, 6))
        valid = np.empty((n, 8), dtype=bool)
        flags = np.empty((n, 8), dtype=np.int64)
        lower = (self.model.lower if limits else np.full(6, -np.inf))[None, :, None]
        upper = (self.model.upper if limits else np.full(6, np.inf))[None, :, None]
        # chunks small enough for the intermediates to stay in cache; (branch, joint, pose) layout
        for a in range(0, n, _CHUNK):
            z = slice(a, min(n, a + _CHUNK))
            m = z.stop - a
            branches = self._batch_solver(*(x[z] for x in rt), *(x[z] for x in p), *(x[z] for x in r), ARRAY_OPS)
            qc = np.empty((8, 6, m))
            ok = np.empty((8, m), dtype=bool)
            fl = np.empty((8, m), dtype=np.int64)
            for b, branch in enumerate(branches):
                for j, value in enumerate(branch.q):
                    qc[b, j] = value
                ok[b] = branch.valid
                fl[b] = branch.flags
            qc, inside = _shift_batch(qc, r[None, :, z], lower, upper)
            ok &= inside
            # branches coincide only at singularities, which are flagged: compare only there
            singular = np.flatnonzero((fl != 0).any(axis=0))
            if singular.size:
                qs, oks = qc[:, :, singular], ok[:, singular]
                for j in range(1, 8):
                    for i in range(j):
                        oks[j] &= ~(oks[i] & (np.abs(qs[j] - qs[i]).max(axis=0) < 1e-9))
                ok[:, singular] = oks
            q[z] = qc.transpose(2, 0, 1)
            valid[z] = ok.T
            flags[z] = fl.T
        q[~valid] = np.nan
        return BatchSolutions(q, valid, flags)


def _shift_into_limits(
    q: Sequence[float], ref: Sequence[float], limits: Sequence[tuple[float, float]]
) -> tuple[float, ...] | None:
    """Each joint moved by a multiple of 2 pi to the value nearest the reference, then (if that
    is outside) to the nearest value inside the limits; None if a joint cannot be brought in."""
    out = []
    for value, r, (lo, hi) in zip(q, ref, limits, strict=True):
        v = value if -math.pi < value - r <= math.pi else r + math.remainder(value - r, _TWO_PI)
        if v < lo - 1e-12:
            v += _TWO_PI * math.ceil((lo - v - 1e-12) / _TWO_PI)
            if v > hi + 1e-12:
                return None
        elif v > hi + 1e-12:
            v -= _TWO_PI * math.ceil((v - hi - 1e-12) / _TWO_PI)
            if v < lo - 1e-12:
                return None
        out.append(v)
    return tuple(out)


def _shift_batch(
    q: NDArray[np.float64], ref: NDArray[np.float64], lower: NDArray[np.float64], upper: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """:func:`_shift_into_limits` for (branch, joint, pose) arrays: (shifted, inside per branch)."""
    v = q - _TWO_PI * np.rint((q - ref) / _TWO_PI)  # as math.remainder: within pi of ref
    below, above = v < lower - 1e-12, v > upper + 1e-12
    if below.any() or above.any():  # the few outside: the nearest value inside, if any
        lo, hi = np.broadcast_to(lower, v.shape), np.broadcast_to(upper, v.shape)
        v[below] += _TWO_PI * np.ceil((lo[below] - v[below] - 1e-12) / _TWO_PI)
        v[above] -= _TWO_PI * np.ceil((v[above] - hi[above] - 1e-12) / _TWO_PI)
    inside = np.all((v >= lower - 1e-12) & (v <= upper + 1e-12), axis=1)
    return v, inside


def _axis_lines(model: RobotModel) -> tuple[list[Matrix], list[Matrix]]:
    """Each joint's axis direction and a point on it, in the base frame at q = 0."""
    lines = chain(TRACE_OPS, model, [0.0] * model.dof, with_axes=True).axes  # plain floats: computed
    axes = [np.array([float(x) for x in line.direction]) for line in lines]
    points = [np.array([float(x) for x in line.point]) for line in lines]
    return axes, points


def _common_normal_feet(p1: Matrix, d1: Matrix, p2: Matrix, d2: Matrix) -> tuple[Matrix, Matrix]:
    """The closest points of two lines (for parallel lines: p1 and its projection on line 2)."""
    r = p2 - p1
    b = float(np.dot(d1, d2))
    denominator = 1.0 - b * b
    if denominator < 1e-15:
        return p1, p2 - np.dot(r, d2) * d2
    e, f = float(np.dot(d1, r)), float(np.dot(d2, r))
    s = (e - b * f) / denominator
    t = (b * e - f) / denominator
    return p1 + s * d1, p2 + t * d2


def _wrist_centre(name: str, axes: list[Matrix], points: list[Matrix]) -> Matrix:
    for i, j in ((0, 1), (1, 2)):
        if np.linalg.norm(np.cross(axes[i], axes[j])) < 1e-6:
            raise NotApplicable(f"{name}: wrist axes {i + 4} and {j + 4} are parallel")
    a, b = _common_normal_feet(points[0], axes[0], points[1], axes[1])
    c, d = _common_normal_feet(points[1], axes[1], points[2], axes[2])
    if np.linalg.norm(a - b) > _GEOMETRY_TOL or np.linalg.norm(c - d) > _GEOMETRY_TOL or np.linalg.norm(b - c) > 1e-9:
        raise NotApplicable(f"{name}: axes 4, 5 and 6 do not meet in one point (not a spherical wrist)")
    return b


_SOLVERS: weakref.WeakKeyDictionary[RobotModel, ClosedFormIK | NotApplicable] = weakref.WeakKeyDictionary()


def closed_form(model: RobotModel) -> ClosedFormIK | None:
    """The model's closed-form solver, or None if its geometry does not admit one."""
    solver = _SOLVERS.get(model)
    if solver is None:
        try:
            solver = ClosedFormIK(model)
        except NotApplicable as exc:
            solver = exc
        _SOLVERS[model] = solver
    return solver if isinstance(solver, ClosedFormIK) else None
