"""LoopThread: an interrupt at any point of a call leaves no coroutine running or unawaited."""

import asyncio
import gc
import threading

import pytest

from rafi.deploy import opcua_loop
from rafi.deploy.opcua_loop import LoopThread, call_within

pytestmark = [
    pytest.mark.filterwarnings("error::RuntimeWarning"),  # "coroutine ... was never awaited"
    pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning"),
]


class Work:
    """A coroutine that waits on the loop and records how it ended, and in which thread."""

    def __init__(self):
        self.started = threading.Event()
        self.ended = []

    async def __call__(self):
        self.started.set()
        try:
            await asyncio.sleep(30)
        except BaseException as exc:
            self.ended.append((type(exc).__name__, threading.current_thread().name))
            raise


def interrupt_scheduling(monkeypatch, *, queue_first: bool, wait_started: Work | None = None):
    """Make the first ``run_coroutine_threadsafe`` of the loop module raise KeyboardInterrupt,
    after queueing the coroutine (``queue_first``) or before, as a Ctrl-C landing inside it."""
    real = asyncio.run_coroutine_threadsafe
    calls = []

    def scheduling(coro, loop):
        calls.append(coro)
        if len(calls) > 1:
            return real(coro, loop)
        if queue_first:
            real(coro, loop)
            if wait_started is not None:
                assert wait_started.started.wait(10)
        raise KeyboardInterrupt

    monkeypatch.setattr(opcua_loop.asyncio, "run_coroutine_threadsafe", scheduling)
    return calls


def test_an_interrupt_after_the_coroutine_started_cancels_it_on_the_loop(monkeypatch):
    loop_thread, work = LoopThread("test-loop"), Work()
    calls = interrupt_scheduling(monkeypatch, queue_first=True, wait_started=work)
    with pytest.raises(KeyboardInterrupt):
        loop_thread.run(work(), timeout_s=10, settle_s=5)
    assert len(calls) == 2  # the cancel went through the loop
    assert work.ended == [("CancelledError", "test-loop")]
    loop_thread.stop(5)
    gc.collect()


def test_an_interrupt_after_the_coroutine_was_queued_cancels_it_before_or_after_it_starts(monkeypatch):
    loop_thread, work = LoopThread("test-loop"), Work()
    loop_thread.run(asyncio.sleep(0), timeout_s=10, settle_s=5)  # the loop runs
    gate = threading.Event()
    loop_thread._loop.call_soon_threadsafe(gate.wait, 10)  # the loop is busy when it is queued
    interrupt_scheduling(monkeypatch, queue_first=True)
    threading.Timer(0.2, gate.set).start()
    with pytest.raises(KeyboardInterrupt):
        loop_thread.run(work(), timeout_s=10, settle_s=5)
    assert work.ended in ([], [("CancelledError", "test-loop")])  # cancelled before its first step, or in it
    assert not [t for t in asyncio.all_tasks(loop_thread._loop) if not t.done()]
    loop_thread.stop(5)
    gc.collect()


def test_an_interrupt_before_the_coroutine_was_queued_closes_it_unrun(monkeypatch):
    loop_thread, work = LoopThread("test-loop"), Work()
    loop_thread.run(asyncio.sleep(0), timeout_s=10, settle_s=5)
    interrupt_scheduling(monkeypatch, queue_first=False)
    with pytest.raises(KeyboardInterrupt):
        loop_thread.run(work(), timeout_s=10, settle_s=5)
    assert not work.started.is_set() and work.ended == []
    loop_thread.stop(5)
    gc.collect()  # an unclosed coroutine would warn "never awaited" here


def test_an_interrupt_before_the_loop_exists_closes_the_coroutine(monkeypatch):
    loop_thread, work = LoopThread("test-loop"), Work()
    interrupt_scheduling(monkeypatch, queue_first=False)
    monkeypatch.setattr(loop_thread, "_start", lambda: (_ for _ in ()).throw(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        loop_thread.run(work(), timeout_s=10, settle_s=5)
    assert not loop_thread.running and not work.started.is_set()
    gc.collect()


def test_stop_cancels_what_still_runs_and_stopping_twice_does_nothing():
    loop_thread, work = LoopThread("test-loop-stop"), Work()
    loop_thread.run(asyncio.sleep(0), timeout_s=10, settle_s=5)
    asyncio.run_coroutine_threadsafe(work(), loop_thread._loop)
    assert work.started.wait(10)
    loop_thread.stop(5)
    loop_thread.stop(5)
    assert work.ended == [("CancelledError", "test-loop-stop")]
    assert not loop_thread.running
    assert not [t for t in threading.enumerate() if t.name == "test-loop-stop"]


def test_call_within_returns_times_out_and_makes_no_coroutine_it_does_not_run(monkeypatch):
    loop_thread, made = LoopThread("test-loop-call"), []

    async def answer(value, delay_s=0.0):
        made.append(value)
        await asyncio.sleep(delay_s)
        return value

    assert loop_thread.run(call_within(5, answer, 42), timeout_s=10, settle_s=5) == 42
    with pytest.raises(TimeoutError):
        loop_thread.run(call_within(0.05, answer, 1, 30), timeout_s=10, settle_s=5)
    interrupt_scheduling(monkeypatch, queue_first=False)
    with pytest.raises(KeyboardInterrupt):
        loop_thread.run(call_within(5, answer, 2), timeout_s=10, settle_s=5)
    assert made == [42, 1]  # the interrupted call never made its coroutine
    loop_thread.stop(5)
    gc.collect()
