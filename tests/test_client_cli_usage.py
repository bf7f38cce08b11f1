"""``robot-client`` as a user meets it in the second hour (issue 36): the options every command
takes given before the command, the refusals with the controller's reason and a next step, the
model the controller runs, a recording's replay, the demo against a running controller."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from client import cli
from tests.test_client_cli_inprocess import client, controller


async def test_the_common_options_may_come_before_the_command() -> None:
    async with controller(profile="motoros") as (_emu, ports):
        code, out = await client(*ports, "status")  # --profile motoros --motion-port ... status
        assert code == 0, out
        assert '"positions"' in out


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--count", "3", "ping"], "--count is not an option of robot-client itself: a command's own options go after"),
        (["--timeout", "-1", "status"], "argument --timeout: must be > 0"),
        (["--profile", "motorxs", "status"], "argument --profile: invalid choice: 'motorxs'"),
        (["--profile", "motoros", "stauts"], "argument COMMAND: invalid choice: 'stauts'"),
    ],
)
def test_a_mistake_before_the_command_is_named_as_it_is(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv, io.StringIO())
    assert exit_.value.code == cli.EXIT_USAGE
    assert says in capsys.readouterr().err


async def test_the_demo_against_a_running_controller_names_the_options_it_does_not_use(tmp_path: Path) -> None:
    async with controller() as (_emu, ports):
        code, out = await client(
            "demo", *ports, "--short", "--simulated", "--policies", "quintic", "ruckig", "--no-plot", "--no-movl",
            "--output", str(tmp_path),
        )  # fmt: skip
    assert code == 0, out
    assert "a controller answers at 127.0.0.1:" in out
    assert (
        "ignored here: --simulated, --policies quintic ruckig (they choose how the embedded emulator runs; a "
        "running controller interpolates its own way, in real time): add --embedded to run them"
    ) in out
    docs = (Path(__file__).parents[1] / "docs" / "demo.md").read_text()
    shown = next(line for line in docs.splitlines() if line.startswith("ignored here:"))
    assert shown in out  # the docs show what the command prints


async def test_the_demo_says_nothing_is_ignored_when_nothing_is(tmp_path: Path) -> None:
    async with controller() as (_emu, ports):
        code, out = await client("demo", *ports, "--short", "--no-plot", "--no-movl", "--output", str(tmp_path))
    assert code == 0, out
    assert "ignored here" not in out
