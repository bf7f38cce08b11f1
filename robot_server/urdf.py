"""Load a serial chain from a URDF file, with the standard library's XML parser.

Supported joint types: ``revolute``, ``continuous``, ``prismatic`` and ``fixed`` (``floating`` and
``planar`` are not serial-arm joints and are refused). Each joint contributes its ``<origin>``
(xyz in metres, rpy in radians, URDF's fixed-axis roll-pitch-yaw), its ``<axis>`` (normalised) and
its ``<limit>``. Fixed joints fold into the neighbouring transforms: those before the first moving
joint become the model's base, those after the last its tool.

Other elements and attributes (``<link>`` geometry, ``<transmission>``, ``<gazebo>``, ``effort``...)
are URDF's or its tools' and are left alone. Errors are :class:`~.model.ModelError` naming the file
and the joint, with the value as the file writes it (metres, radians): ``arm.urdf: joint 'j2'
limit.lower = 1.5 rad is not below limit.upper = -1.5 rad``.

The chain runs from the root link (the one link that is nobody's child) to a tip link: the leaf
with the most moving joints above it (ties go to the deeper leaf), or the ``tip`` you name. A link
with two parent joints (a closed loop) or a cycle is an error. URDF has no acceleration or jerk
limits; those take the emulator's defaults (docs/kinematics.md, "Adding a model": 10 rad/s^2,
500 rad/s^3, and the same numbers in m/s^2, m/s^3 for prismatic joints). A ``continuous`` joint
gets position limits of +-2 pi, so a controller can still unwind it.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .model import Joint, JointType, ModelError, RobotModel, transform

__all__ = ["load_urdf"]

Matrix = NDArray[np.float64]
_MOVING = {"revolute": JointType.REVOLUTE, "continuous": JointType.REVOLUTE, "prismatic": JointType.PRISMATIC}
_DEFAULT_ACCELERATION = 10.0
_DEFAULT_JERK = 500.0


class _UrdfJoint:
    def __init__(self, path: Path, element: ET.Element, index: int) -> None:
        self.name = element.get("name") or ""
        where = f"joint {self.name!r}" if self.name else f"joint #{index + 1}"
        if not self.name:
            raise ModelError(f"{path}: {where} has no name attribute")
        self.kind = element.get("type") or ""
        if self.kind not in _MOVING and self.kind != "fixed":
            raise ModelError(
                f"{path}: {where} has type {self.kind!r}; supported: revolute, continuous, prismatic, fixed"
            )
        self.parent = _link_ref(path, element, "parent", where)
        self.child = _link_ref(path, element, "child", where)
        origin = element.find("origin")
        xyz = _vector(path, origin, "xyz", where, "origin") if origin is not None else (0.0, 0.0, 0.0)
        rpy = _vector(path, origin, "rpy", where, "origin") if origin is not None else (0.0, 0.0, 0.0)
        self.origin = transform(xyz, rpy)
        axis_element = element.find("axis")
        axis = _vector(path, axis_element, "xyz", where, "axis") if axis_element is not None else (1.0, 0.0, 0.0)
        norm = math.sqrt(sum(v * v for v in axis))
        if self.kind != "fixed" and norm < 1e-12:
            raise ModelError(f"{path}: {where} axis.xyz is the zero vector")
        self.axis = np.array(axis) / (norm if norm else 1.0)
        self.lower, self.upper, self.velocity = -2 * math.pi, 2 * math.pi, math.pi
        limit = element.find("limit")
        unit = "m" if self.kind == "prismatic" else "rad"  # URDF's units, always
        if self.kind in ("revolute", "prismatic"):
            if limit is None:
                raise ModelError(f"{path}: {where} ({self.kind}) has no <limit> element")
            self.lower = _number(path, limit, "lower", where, "limit", default=0.0)
            self.upper = _number(path, limit, "upper", where, "limit", default=0.0)
            if self.lower >= self.upper:
                raise ModelError(
                    f"{path}: {where} limit.lower = {_given(limit, 'lower')} {unit} is not below "
                    f"limit.upper = {_given(limit, 'upper')} {unit}"
                )
        if limit is not None:
            self.velocity = _number(path, limit, "velocity", where, "limit", default=math.pi)
            if self.velocity <= 0:
                raise ModelError(f"{path}: {where} limit.velocity = {_given(limit, 'velocity')} {unit}/s must be > 0")


def _given(element: ET.Element, key: str) -> str:
    """An attribute as the file writes it, or URDF's default 0 when the file leaves it out."""
    text = element.get(key)
    return "0 (not given)" if text is None else text.strip()


def _link_ref(path: Path, element: ET.Element, tag: str, where: str) -> str:
    ref = element.find(tag)
    link = ref.get("link") if ref is not None else None
    if not link:
        raise ModelError(f"{path}: {where} is missing <{tag} link=...>")
    return link


def _number(path: Path, element: ET.Element, key: str, where: str, tag: str, *, default: float) -> float:
    text = element.get(key)
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        raise ModelError(f"{path}: {where} {tag}.{key} = {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ModelError(f"{path}: {where} {tag}.{key} = {text!r} is not finite")
    return value


def _vector(path: Path, element: ET.Element, key: str, where: str, tag: str) -> tuple[float, float, float]:
    text = element.get(key)
    if text is None:
        return (1.0, 0.0, 0.0) if tag == "axis" else (0.0, 0.0, 0.0)
    parts = text.split()
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ModelError(f"{path}: {where} {tag}.{key} = {text!r} is not three numbers") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ModelError(f"{path}: {where} {tag}.{key} = {text!r} is not three finite numbers")
    return values[0], values[1], values[2]


def load_urdf(path: Path, tip: str | None = None) -> RobotModel:
    """A model of the serial chain from the URDF's root link to ``tip`` (default: see module doc)."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ModelError(f"{path}: not well-formed XML: {exc}") from None
    except OSError as exc:
        raise ModelError(f"{path}: cannot read: {exc}") from None
    if root.tag != "robot":
        raise ModelError(f"{path}: the root element is <{root.tag}>, not <robot>")
    name = root.get("name") or path.stem
    links = {link.get("name") for link in root.findall("link")}
    if None in links or "" in links:
        raise ModelError(f"{path}: a <link> has no name attribute")
    joints = [_UrdfJoint(path, element, i) for i, element in enumerate(root.findall("joint"))]
    parent_of: dict[str, _UrdfJoint] = {}
    children: dict[str, list[_UrdfJoint]] = {}
    for joint in joints:
        for end in (joint.parent, joint.child):
            if end not in links:
                raise ModelError(f"{path}: joint {joint.name!r} refers to undefined link {end!r}")
        if joint.child in parent_of:
            other = parent_of[joint.child].name
            raise ModelError(
                f"{path}: closed loop: link {joint.child!r} is the child of both joint {other!r} and joint "
                f"{joint.name!r} (a serial chain needs one parent per link)"
            )
        parent_of[joint.child] = joint
        children.setdefault(joint.parent, []).append(joint)
    roots = sorted(str(link) for link in links if link not in parent_of)
    if len(roots) != 1:
        what = "no root link (the joints form a cycle)" if not roots else f"several root links {roots}"
        raise ModelError(f"{path}: {what}; a robot is one tree of links")
    chain = _chain_to_tip(path, roots[0], children, parent_of, tip)
    return _model_from_chain(path, name, chain)


def _chain_to_tip(
    path: Path, root: str, children: dict[str, list[_UrdfJoint]], parent_of: dict[str, _UrdfJoint], tip: str | None
) -> list[_UrdfJoint]:
    if tip is None:
        best: tuple[int, int, str] | None = None
        stack = [(root, 0, 0)]
        while stack:
            link, moving, depth = stack.pop()
            below = children.get(link, [])
            if not below and (best is None or (moving, depth) > best[:2]):
                best = (moving, depth, link)
            stack.extend((j.child, moving + (j.kind != "fixed"), depth + 1) for j in below)
        assert best is not None
        tip = best[2]
    elif tip != root and tip not in parent_of:
        raise ModelError(f"{path}: tip link {tip!r} is not in the robot")
    chain: list[_UrdfJoint] = []
    link = tip
    while link != root:
        joint = parent_of[link]
        chain.append(joint)
        link = joint.parent
    chain.reverse()
    return chain


def _model_from_chain(path: Path, name: str, chain: list[_UrdfJoint]) -> RobotModel:
    fixed = np.eye(4)
    base: Matrix | None = None
    joints: list[Joint] = []
    for urdf_joint in chain:
        if urdf_joint.kind == "fixed":
            fixed = fixed @ urdf_joint.origin
            continue
        pre = urdf_joint.origin
        if base is None:
            base, pre = fixed @ pre, np.eye(4)
        else:
            pre = fixed @ pre
        fixed = np.eye(4)
        joints.append(
            Joint(
                name=urdf_joint.name,
                type=_MOVING[urdf_joint.kind],
                pre=pre,
                axis=urdf_joint.axis,
                post=np.eye(4),
                position=(urdf_joint.lower, urdf_joint.upper),
                velocity=urdf_joint.velocity,
                acceleration=_DEFAULT_ACCELERATION,
                jerk=_DEFAULT_JERK,
            )
        )
    if not joints:
        raise ModelError(f"{path}: the chain to the tip has no moving joints")
    return RobotModel(
        name=name,
        joints=tuple(joints),
        base=base if base is not None else np.eye(4),
        tool=fixed,
        description=f"from URDF {path.name}",
        source=str(path),
        convention="urdf",
    )
