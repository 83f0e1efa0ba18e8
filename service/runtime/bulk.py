"""Bulk work of the web process (dataset downloads, imports) on its own low-priority threads.

Downloads and imports are streamed in bounded chunks, so none holds the interpreter lock for long;
running them here instead of in the request thread pool also keeps them from taking the threads
that short requests (and the token check of an emergency stop) need, and from competing for the
CPU on equal terms with the event loop: on Linux each bulk thread lowers its own scheduling
priority (``nice`` +10, best effort; a thread may always lower its own priority).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import TypeVar

from service.runtime.priority import BULK_NICE, set_thread_nice

#: threads for bulk work: more downloads or imports than this wait their turn (they are not refused)
BULK_WORKERS = 4

T = TypeVar("T")


_POOL = ThreadPoolExecutor(
    max_workers=BULK_WORKERS, thread_name_prefix="evc-bulk", initializer=set_thread_nice, initargs=(BULK_NICE,)
)


async def run_bulk(fn: Callable[..., T], *args) -> T:
    """``fn(*args)`` on a bulk thread; the event loop stays free meanwhile."""
    return await asyncio.get_running_loop().run_in_executor(_POOL, partial(fn, *args))


async def iterate_bulk(chunks: Iterator[T]) -> AsyncIterator[T]:
    """The items of a blocking iterator, each produced on a bulk thread (for a StreamingResponse).
    The iterator is closed on a bulk thread too when the client goes away."""
    loop, end = asyncio.get_running_loop(), object()
    try:
        while True:
            item = await loop.run_in_executor(_POOL, next, chunks, end)
            if item is end:
                return
            yield item
    finally:
        close = getattr(chunks, "close", None)
        if close is not None:
            await loop.run_in_executor(_POOL, close)
