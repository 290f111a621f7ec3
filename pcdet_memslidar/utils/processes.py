"""Worker processes that end with their parent, and a bounded map over a process or thread pool."""
from __future__ import annotations

import itertools
import os
import threading
import time
from collections import deque
from concurrent.futures import Executor
from typing import Callable, Iterable, Iterator

PARENT_POLL_S = 0.5  # how often a worker checks that its parent is still alive


def exit_with_parent() -> None:
    """Pool initializer: end this worker within PARENT_POLL_S once its parent is gone (e.g. killed with kill -9,
    which leaves no chance to stop the pool), instead of running on unattended."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def bounded_map(pool: Executor, function: Callable, items: Iterable, ahead: int) -> Iterator:
    """pool.map(function, items) that submits at most `ahead` items before their results are taken, so a very
    long (or lazy) `items` is never materialised as futures all at once. Yields results in order."""
    items = iter(items)
    pending = deque(pool.submit(function, item) for item in itertools.islice(items, ahead))
    while pending:
        result = pending.popleft().result()
        pending.extend(pool.submit(function, item) for item in itertools.islice(items, 1))
        yield result
