"""``python -m robot_server.kinematics``: forward and inverse kinematics for people and for other
languages. Angles in radians, lengths in metres, JSON on stdout, errors on stderr (exit status 2).

    fk --model NAME|PATH Q1 ... QN              -> {"T": [[...], ...]}
    ik --model NAME|PATH --pose JSON [--seed Q1 ... QN] [--all]
                                                -> {"solutions": [[...], ...]}
    models                                      -> {"models": [{"name": ..., ...}, ...]}

``--pose`` takes a 4x4 matrix as JSON (nested lists, or ``{"T": ...}`` as ``fk`` prints it).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..loader import load_model, shipped_models
from ..model import ModelError
from . import IKFailed, closed_form, fk, ik


def _pose(text: str) -> np.ndarray[Any, Any]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--pose is not valid JSON: {exc}") from None
    if isinstance(data, dict):
        data = data.get("T")
    try:
        pose = np.array(data, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("--pose must be a 4x4 matrix of numbers") from None
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"--pose must be a finite 4x4 matrix, not shape {pose.shape}")
    if not np.allclose(pose[3], [0, 0, 0, 1]) or not np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-6):
        raise ValueError("--pose must be a homogeneous transform: orthonormal rotation, last row 0 0 0 1")
    return pose


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m robot_server.kinematics",
        description="Forward and inverse kinematics of the robot models, for people and for other languages. "
        "Angles in radians, lengths in metres, JSON on stdout, errors on stderr (exit status 2).",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p_fk = sub.add_parser("fk", help="flange pose of a configuration")
    p_fk.add_argument("--model", required=True, help="shipped model name or a .toml/.urdf path")
    p_fk.add_argument("q", nargs="+", type=float, help="joint values (rad or m)")
    p_ik = sub.add_parser("ik", help="configurations reaching a pose")
    p_ik.add_argument("--model", required=True, help="shipped model name or a .toml/.urdf path")
    p_ik.add_argument("--pose", required=True, help="4x4 pose as JSON")
    p_ik.add_argument("--seed", nargs="+", type=float, help="configuration to stay near")
    p_ik.add_argument("--all", action="store_true", help="every solution (closed-form models)")
    sub.add_parser("models", help="list the shipped models")
    args = parser.parse_args(argv)
    try:
        if args.command == "models":
            listing = []
            for name in shipped_models():
                model = load_model(name)
                listing.append(
                    {
                        "name": name,
                        "dof": model.dof,
                        "description": model.description,
                        "closed_form_ik": closed_form(model) is not None,
                    }
                )
            print(json.dumps({"models": listing}))
            return 0
        model = load_model(args.model)
        if args.command == "fk":
            if len(args.q) != model.dof:
                raise ValueError(f"{model.name} has {model.dof} joints; got {len(args.q)} values")
            print(json.dumps({"T": fk(model, args.q).tolist()}))
            return 0
        pose = _pose(args.pose)
        if args.seed is not None and len(args.seed) != model.dof:
            raise ValueError(f"--seed needs {model.dof} values for {model.name}; got {len(args.seed)}")
        solutions = ik(model, pose, args.seed, all=args.all)
        print(json.dumps({"solutions": [list(s.q) for s in solutions]}))
        return 0
    except (ModelError, ValueError, IKFailed) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
