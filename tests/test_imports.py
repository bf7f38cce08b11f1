"""The layers import clean: each one loads what it needs and not the layers above it.

Importing the codec, the framing or the sans-I/O link loads no asyncio, endpoints or capture code;
importing a robot model or the kinematics loads no emulator, controller or web view; the client's
driver and planner load no emulator. Each rule is checked in a fresh interpreter (the test process
has everything loaded already), and the package roots still give every public name, lazily.
"""

from __future__ import annotations

import ast
import fnmatch
import json
import subprocess
import sys
from pathlib import Path

import pytest

import robot_server
import robot_server.control
import simple_message

ROOT = Path(__file__).resolve().parent.parent

#: the I/O side of simple_message (and what reads and writes captures)
IO = ("asyncio", "simple_message.endpoints", "simple_message.connection", "simple_message.capture*", "dpkt*")
#: the emulator, the controller that runs motion, and the web view
EMULATOR = (
    "robot_server.emulator*",
    "robot_server.control.controller",
    "robot_server.control.loop",
    "robot_server.control.motion",
    "robot_server.web*",
    "aiohttp*",
)

#: (what is imported, what must not be loaded then)
RULES = {
    "codec, framing and link": (
        [
            "simple_message",
            "simple_message.constants",
            "simple_message.errors",
            "simple_message.wire",
            "simple_message.messages",
            "simple_message.framing",
            "simple_message.header",
            "simple_message.dialects",
            "simple_message.link",
            "simple_message.jsonio",
        ],
        IO,
    ),
    "robot model and kinematics": (
        [
            "robot_server",
            "robot_server.model",
            "robot_server.loader",
            "robot_server.urdf",
            "robot_server.workspace",
            "robot_server.kinematics",
            "robot_server.control",
        ],
        IO + EMULATOR,
    ),
    "client planner": (["client.planner"], IO + EMULATOR),
    "client driver": (["client.driver"], EMULATOR),
    "client command": (["client.cli"], ("robot_server.emulator*", "robot_server.web*", "aiohttp*")),
}


def loaded_after(code: str) -> list[str]:
    """The modules a fresh interpreter holds after running ``code``."""
    run = subprocess.run(
        [sys.executable, "-c", f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    modules: list[str] = json.loads(run.stdout.splitlines()[-1])
    return modules


@pytest.mark.parametrize("rule", list(RULES))
def test_a_layer_loads_no_layer_above_it(rule: str) -> None:
    imported, forbidden = RULES[rule]
    modules = loaded_after("\n".join(f"import {name}" for name in imported))
    assert set(imported) <= set(modules)
    wrong = [name for name in modules if any(fnmatch.fnmatchcase(name, pattern) for pattern in forbidden)]
    assert wrong == [], f"importing {', '.join(imported)} loads {', '.join(wrong)}"


def test_the_package_roots_still_give_every_public_name() -> None:
    code = """
from simple_message import NEED_DATA, Client, Link, read_capture
from simple_message import *
from robot_server import *
import simple_message, robot_server, robot_server.control
for package in (simple_message, robot_server, robot_server.control):
    missing = [name for name in package.__all__ if not hasattr(package, name)]
    assert not missing, (package.__name__, missing)
    assert set(package.__all__) <= set(dir(package)), package.__name__
assert simple_message.endpoints.Client is Client and simple_message.link.NEED_DATA is NEED_DATA
"""
    assert "robot_server.emulator" in loaded_after(code)


def test_the_link_events_are_exported_with_it() -> None:
    from simple_message import link

    assert set(link.__all__) <= set(simple_message.__all__)
    for name in link.__all__:
        assert getattr(simple_message, name) is getattr(link, name)


def test_an_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'Nothing'"):
        _ = simple_message.Nothing  # type: ignore[attr-defined]
    with pytest.raises(ImportError):
        from robot_server import Nothing  # type: ignore[attr-defined]  # noqa: F401


def _declared(package: object) -> dict[str, str]:
    """name -> module of the ``if TYPE_CHECKING:`` imports of a package's ``__init__``."""
    path = Path(package.__file__)  # type: ignore[attr-defined]
    tree = ast.parse(path.read_text(), str(path))
    names = {}
    for node in tree.body:
        if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
            for imp in node.body:
                assert isinstance(imp, ast.ImportFrom)
                names.update({alias.name: "." * imp.level + (imp.module or "") for alias in imp.names})
    return names


@pytest.mark.parametrize("package", [simple_message, robot_server, robot_server.control], ids=lambda p: p.__name__)
def test_the_lazy_table_agrees_with_the_typed_imports_and_all(package: object) -> None:
    declared = _declared(package)
    assert declared == package._EXPORTS.origin  # type: ignore[attr-defined]
    assert sorted(declared) == sorted(package.__all__)  # type: ignore[attr-defined]


def test_the_paths_that_moved_still_import() -> None:
    """Issue 37 moved the capture writer into the capture package and renamed the server suite's
    link: the old import paths give the same objects."""
    from simple_message.capture import CaptureWriter
    from simple_message.capture_writer import CaptureWriter as OldWriter
    from simple_message.conformance.links import Link, ProbeLink

    assert OldWriter is CaptureWriter and Link is ProbeLink
