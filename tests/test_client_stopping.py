"""The STOP after an abort (client/stopping.py): it runs to its end though the caller is
cancelled, a stop that could not be sent is a warning, and its outcome is always retrieved (a
cancelled caller used to leave asyncio's "Task exception was never retrieved" behind)."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
from typing import Any

import pytest

from client.errors import DriverError
from client.stopping import stop_after_abort
from simple_message.errors import ConnectionClosed


class Unretrieved:
    """Catches what the event loop's exception handler is given (an unretrieved task exception)."""

    def __init__(self) -> None:
        self.seen: list[dict[str, Any]] = []

    def __call__(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        self.seen.append(context)


async def test_a_stop_sent_is_quiet(caplog: pytest.LogCaptureFixture) -> None:
    sent: list[str] = []

    async def stop() -> None:
        sent.append("STOP")

    with caplog.at_level(logging.INFO, "client.driver"):
        await stop_after_abort(stop())
    assert sent == ["STOP"] and caplog.text == ""


NOT_SENT = [DriverError("no reply to JOINT_TRAJ_PT"), ConnectionClosed("closed"), TimeoutError()]


@pytest.mark.parametrize("error", NOT_SENT)
async def test_a_stop_not_sent_is_a_warning_not_an_error_raised(
    error: Exception, caplog: pytest.LogCaptureFixture
) -> None:
    async def stop() -> None:
        raise error

    with caplog.at_level(logging.INFO, "client.driver"):
        await stop_after_abort(stop(), "line STOP")
    assert "the line STOP after the abort was not sent" in caplog.text
    assert "the robot may still be moving" in caplog.text
    assert [r.levelno for r in caplog.records] == [logging.WARNING]


async def test_a_bug_in_the_stop_is_raised() -> None:
    async def stop() -> None:
        raise ZeroDivisionError

    with pytest.raises(ZeroDivisionError):
        await stop_after_abort(stop())


@pytest.mark.parametrize("outcome", ["sent", "not sent", "bug"])
async def test_a_cancelled_caller_leaves_the_stop_running_and_its_outcome_logged(
    outcome: str, caplog: pytest.LogCaptureFixture
) -> None:
    loop = asyncio.get_running_loop()
    unretrieved = Unretrieved()
    loop.set_exception_handler(unretrieved)
    release = asyncio.Event()
    started = asyncio.Event()
    done: list[str] = []

    async def stop() -> None:
        started.set()
        await release.wait()
        if outcome == "not sent":
            raise ConnectionClosed("motion 127.0.0.1:1: closed")
        if outcome == "bug":
            raise ZeroDivisionError("a bug")
        done.append("STOP")

    try:
        with caplog.at_level(logging.INFO, "client.driver"):
            caller = asyncio.ensure_future(stop_after_abort(stop()))
            async with asyncio.timeout(10.0):
                await started.wait()
            caller.cancel()
            with pytest.raises(asyncio.CancelledError):
                await caller
            assert caplog.text == ""  # the stop is still under way
            release.set()
            # the stop's task (its outcome callback, added first, runs before asyncio.wait's)
            others = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            assert len(others) == 1
            _, pending = await asyncio.wait(others, timeout=10.0)
            assert not pending
            gc.collect()  # an unretrieved exception is reported when its task is collected
            await asyncio.sleep(0)
    finally:
        loop.set_exception_handler(None)
    assert unretrieved.seen == []
    if outcome == "sent":
        assert done == ["STOP"] and caplog.text == ""
    elif outcome == "not sent":
        assert [r.levelno for r in caplog.records] == [logging.WARNING]
        assert "the STOP after the abort was not sent (motion 127.0.0.1:1: closed)" in caplog.text
    else:
        assert [r.levelno for r in caplog.records] == [logging.ERROR]
        assert "the STOP after the abort failed" in caplog.text and "ZeroDivisionError: a bug" in caplog.text


async def test_without_the_retrieval_asyncio_complains() -> None:
    """The check above can see the defect: a shielded task whose caller left, failing unretrieved."""
    loop = asyncio.get_running_loop()
    unretrieved = Unretrieved()
    loop.set_exception_handler(unretrieved)
    release = asyncio.Event()

    async def stop() -> None:
        await release.wait()
        raise ConnectionClosed("closed")

    async def old_way() -> None:
        with contextlib.suppress(ConnectionClosed):
            await asyncio.shield(stop())

    try:
        caller = asyncio.ensure_future(old_way())
        await asyncio.sleep(0)
        caller.cancel()
        with pytest.raises(asyncio.CancelledError):
            await caller
        release.set()
        for _ in range(3):
            await asyncio.sleep(0)
        gc.collect()
        await asyncio.sleep(0)
    finally:
        loop.set_exception_handler(None)
    assert [c["message"] for c in unretrieved.seen] == ["Task exception was never retrieved"]
