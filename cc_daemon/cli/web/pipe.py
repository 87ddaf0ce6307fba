"""A download's bytes, from the thread that writes them to the loop that sends them.

The exporters write to a text file (`write(str)`); a download must not hold the
whole file. `Pipe` is that file: its writer runs on a thread of its own and
blocks once `AHEAD` chunks wait unsent, so a survey of any length costs a few
chunks of memory, and a client that reads slowly slows the writer instead of
filling the Pi's memory. When the client leaves, the next write raises
`BrokenPipeError`, so the writer unwinds (closing the journal, removing its
temporary files) on its own thread. This module knows nothing of HTTP or the
journal.
"""

from __future__ import annotations

import asyncio
import io
import threading
from collections.abc import AsyncGenerator, Callable
from concurrent.futures import Executor
from typing import TextIO, cast

CHUNK = 64 * 1024
AHEAD = 4  # chunks the writer may be ahead of the client


class _End:
    """The writer is done: `error` None, or what stopped it."""

    def __init__(self, error: BaseException | None) -> None:
        self.error = error


class Pipe(io.TextIOBase):
    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__()
        self._loop = loop
        self._queue: asyncio.Queue[bytes | _End] = asyncio.Queue()
        self._room = threading.Semaphore(AHEAD)
        self._parts: list[str] = []
        self._size = 0
        self._gone = False

    # --- the writer's side (its own thread)

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        if self._gone:
            raise BrokenPipeError("the client left")
        self._parts.append(text)
        self._size += len(text)
        if self._size >= CHUNK:
            self._send()
        return len(text)

    def as_text(self) -> TextIO:
        """For the exporters, which take a text file and only ever call `write`."""
        return cast(TextIO, self)

    def write_bytes(self, data: bytes) -> None:
        """A binary file's bytes (NetCDF), as they come."""
        if self._parts:
            self._send()
        self._put(data)

    def _send(self) -> None:
        data = "".join(self._parts).encode()
        self._parts, self._size = [], 0
        self._put(data)

    def _put(self, item: bytes | _End) -> None:
        self._room.acquire()
        if self._gone and not isinstance(item, _End):
            raise BrokenPipeError("the client left")
        self._loop.call_soon_threadsafe(self._queue.put_nowait, item)

    def _finish(self, error: BaseException | None) -> None:
        if error is None and self._parts and not self._gone:
            self._send()
        self._put(_End(error))

    # --- the loop's side

    async def run(
        self, executor: Executor, writer: Callable[[Pipe], None]
    ) -> AsyncGenerator[bytes, None]:
        """Run `writer(self)` on `executor` and yield what it writes, chunk by chunk;
        what stopped it is raised here (after any chunk it wrote before)."""
        loop = self._loop

        def work() -> None:
            try:
                writer(self)
            except BaseException as exc:  # handed to the loop, raised there
                self._finish(exc)
            else:
                self._finish(None)

        done = loop.run_in_executor(executor, work)
        try:
            while True:
                item = await self._queue.get()
                self._room.release()
                if isinstance(item, _End):
                    if item.error is not None:
                        raise item.error
                    return
                yield item
        finally:
            self._gone = True
            for _ in range(AHEAD + 1):  # wake a writer waiting for room: it sees _gone
                self._room.release()
            await asyncio.shield(done)
