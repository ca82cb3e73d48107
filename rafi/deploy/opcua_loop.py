"""An asyncio event loop in a thread of its own, for a synchronous caller that may be interrupted.

The OPC UA link (:class:`rafi.deploy.opcua_client.OpcUaLink`) runs asyncua's client on such a
loop, so that the live loop can call it like any function. The caller's thread is the main
thread, where Ctrl-C and SIGTERM arrive (as KeyboardInterrupt): :meth:`LoopThread.run` then
cancels the coroutine's task *on the loop* and lets the interrupt go on, and
:meth:`LoopThread.stop` cancels whatever still runs there (a library's background tasks)
before it stops the thread, so that nothing is left pending ("Task was destroyed but it is
pending!") and nothing runs after the loop is closed ("no running event loop").
Standard library only.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import threading
from collections.abc import Callable

__all__ = ["LoopThread", "call_within"]


class LoopThread:
    """A daemon thread running an event loop, started by the first :meth:`run`.

    Parameters
    ----------
    name : str
        The thread's name.
    on_start, on_stop : callable, optional
        ``f(thread_ident)`` once the thread runs / once it has stopped (e.g. to route the log
        records the thread makes).
    """

    def __init__(self, name: str, *, on_start: Callable | None = None, on_stop: Callable | None = None):
        self.name = name
        self.on_start = on_start
        self.on_stop = on_stop
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self._loop is not None

    def _start(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.new_event_loop()
            self._thread = threading.Thread(target=self._loop.run_forever, name=self.name, daemon=True)
            self._thread.start()
            if self.on_start is not None:
                self.on_start(self._thread.ident)
        return self._loop

    def run(self, coro, timeout_s: float, settle_s: float):
        """Run ``coro`` on the loop and return its result.

        Raises
        ------
        TimeoutError
            No result within ``timeout_s`` (the task is cancelled).
        KeyboardInterrupt, SystemExit
            Raised in the caller's thread while it waited: the task is cancelled on the loop,
            awaited at most ``settle_s``, and the interrupt raised again.
        """
        future = None
        try:
            future = asyncio.run_coroutine_threadsafe(coro, self._start())
            return future.result(timeout_s)
        except TimeoutError:
            future.cancel()
            raise
        except BaseException:
            if future is None:
                self._cancel_unknown(coro, settle_s)
            elif not future.done():
                future.cancel()
                concurrent.futures.wait([future], timeout=settle_s)
            raise

    def _cancel_unknown(self, coro, settle_s: float) -> None:
        """Cancel ``coro`` after an interrupt inside the scheduling call: it may already run on
        the loop (the interrupt came after the call had queued it) or never will. Decided on
        the loop, after anything already queued there; closing it from this thread while the
        loop steps it would throw into a running coroutine."""
        loop = self._loop
        if loop is None:
            coro.close()  # no loop yet: it was never scheduled
            return

        async def cancel():
            task = next((t for t in asyncio.all_tasks() if t.get_coro() is coro), None)
            if task is None:
                coro.close()  # never scheduled: it never runs
            else:
                task.cancel()
                await asyncio.wait([task], timeout=settle_s)

        try:
            asyncio.run_coroutine_threadsafe(cancel(), loop).result(settle_s + 1)
        except BaseException:  # an interrupt again: stop() cancels what is left
            pass

    def stop(self, timeout_s: float) -> None:
        """Cancel every task still on the loop (waiting at most ``timeout_s``), stop the loop
        and its thread, close it. Stopping twice does nothing."""
        loop, self._loop = self._loop, None
        if loop is None:
            return

        async def cancel_pending():
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            if tasks:
                await asyncio.wait(tasks, timeout=timeout_s)

        try:
            asyncio.run_coroutine_threadsafe(cancel_pending(), loop).result(timeout_s + 1)
        except BaseException:  # an interrupt again, or a task that would not end: stop anyway
            pass
        finally:
            loop.call_soon_threadsafe(loop.stop)
            thread, self._thread = self._thread, None
            thread.join(timeout_s + 1)
            if not thread.is_alive():
                loop.close()
            if self.on_stop is not None:
                self.on_stop(thread.ident)


async def call_within(timeout_s: float, fn: Callable, *args):
    """``await fn(*args)`` for at most ``timeout_s`` (TimeoutError after). The coroutine is made
    here, on the loop, in the caller's task: a call that never gets to run leaves no coroutine
    behind ("never awaited"), and no second task is left for a cancel to strand."""
    async with asyncio.timeout(timeout_s):
        return await fn(*args)
