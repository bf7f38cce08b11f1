"""``robot-client`` as a user meets it in the second hour (issue 36): the options every command
takes given before the command, the refusals with the controller's reason and a next step, the
model the controller runs, a recording's replay, the demo against a running controller."""

from __future__ import annotations

import io

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
