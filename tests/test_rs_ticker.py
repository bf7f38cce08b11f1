"""The state topics' ticker (robot_server.emulator.ticker): many tasks' deadlines, on a Linux
timerfd the event loop watches or on a helper thread, never early, in deadline order."""

from __future__ import annotations

import asyncio
import sys
import time

import pytest

from robot_server.emulator import ticker as ticker_module
from robot_server.emulator.ticker import Ticker


@pytest.fixture(params=["timerfd", "thread"])
def kind(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    if request.param == "thread":
        monkeypatch.setattr(ticker_module._TimerFd, "make", classmethod(lambda cls: None))
    elif not sys.platform.startswith("linux"):
        pytest.skip("a timerfd is Linux's")
    return str(request.param)


async def test_many_deadlines_wake_in_order_and_never_early(kind: str) -> None:
    ticker = Ticker()
    assert ticker.kind == kind
    woke: list[tuple[float, float]] = []
    base = time.monotonic() + 0.01

    async def sleeper(deadline: float) -> None:
        await ticker.sleep_until(deadline)
        woke.append((deadline, time.monotonic()))

    deadlines = [base + 0.0007 * ((k * 37) % 50) for k in range(50)]  # out of order, some equal
    try:
        async with asyncio.timeout(10.0):
            await asyncio.gather(*(sleeper(d) for d in deadlines))
    finally:
        ticker.close()
    assert len(woke) == 50
    assert all(at >= deadline for deadline, at in woke), "never before its deadline"
    assert [d for d, _ in woke] == sorted(d for d, _ in woke), "in deadline order"


async def test_a_cancelled_sleeper_leaves_the_others_on_time(kind: str) -> None:
    ticker = Ticker()
    try:
        early = asyncio.ensure_future(ticker.sleep_until(time.monotonic() + 0.005))
        later = asyncio.ensure_future(ticker.sleep_until(time.monotonic() + 0.01))
        early.cancel()
        async with asyncio.timeout(10.0):
            await later
        assert early.cancelled()
        await ticker.sleep_until(time.monotonic() - 1.0)  # a deadline passed: at once
    finally:
        ticker.close()
    with pytest.raises(RuntimeError, match="closed"):
        await ticker.sleep_until(time.monotonic() + 1.0)
