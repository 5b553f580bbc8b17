"""``run``: a coroutine to its end in an event loop of its own, in a thread of its own.

``asyncio.run`` refuses to start where an event loop already runs in the thread. In a pytest-xdist worker that
ran a browser test first, Playwright's sync API keeps one running in the main thread for the session."""

from __future__ import annotations

import asyncio
from concurrent.futures import ThreadPoolExecutor


def run(coroutine):
    """What ``coroutine`` returns (or raises), run by ``asyncio.run`` in a new thread."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="isorig-test-aio") as pool:
        return pool.submit(asyncio.run, coroutine).result()
