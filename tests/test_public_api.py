"""The packages' public surfaces: what they export exists, and the client uses nothing else.

The client is the first user of the other two packages, so it may import only names a module
lists in ``__all__`` (its public API); everything in an ``__all__`` must exist.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

import robot_server
import simple_message
from simple_message import LE32, CommType, Header, JointTrajPt, MsgType, read_header

ROOT = Path(__file__).resolve().parent.parent


def _imports(package: str) -> list[tuple[str, str, str]]:
    """(file, module, name) for every ``from robot_server/simple_message... import name``."""
    found = []
    for path in sorted((ROOT / package).glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if (
                isinstance(node, ast.ImportFrom)
                and node.module
                and node.level == 0
                and node.module.split(".")[0] in ("robot_server", "simple_message")
            ):
                found += [(path.name, node.module, alias.name) for alias in node.names]
    return found


@pytest.mark.parametrize(("file", "module", "name"), _imports("client"))
def test_the_client_imports_only_public_names(file: str, module: str, name: str) -> None:
    exported = getattr(importlib.import_module(module), "__all__", None)
    assert exported is not None, f"{file}: {module} declares no public API (__all__)"
    assert name in exported, f"{file} imports {name} from {module}, which does not export it"


@pytest.mark.parametrize("package", [simple_message, robot_server])
def test_everything_exported_exists(package: object) -> None:
    missing = [name for name in package.__all__ if not hasattr(package, name)]  # type: ignore[attr-defined]
    assert missing == []


def test_the_endpoints_are_exported_with_their_errors() -> None:
    for name in ("Server", "Client", "Connection", "Link", "Dialect", "ConnectionClosed", "RequestTimeout"):
        assert name in simple_message.__all__


def test_read_header_reads_prefix_and_header() -> None:
    frame = JointTrajPt(7, (0.1,) * 6, 0.5, 1.0).encode(LE32)
    header = read_header(frame, LE32)
    assert isinstance(header, Header)
    fields = (header.length, header.msg_type, header.comm_type, header.reply_code)
    assert fields == (len(frame) - 4, MsgType.JOINT_TRAJ_PT, CommType.SERVICE_REQUEST, 0)
