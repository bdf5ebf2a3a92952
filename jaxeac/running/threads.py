"""Work shared between threads: values computed once per key, and work on a thread of its own.

Compiled programs are built once per key by whichever thread asks first; the others wait for
it (`OnceCache`). A run's compiles ahead of its chunks, and a study's tuning beside its runs,
go on daemon threads, so an interrupted command does not wait for them (`in_background`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from concurrent.futures import Future


class OnceCache:
    """Values computed once per key across threads: the first caller computes, later callers (on
    any thread) wait for its result; a computation that fails or is interrupted is forgotten, so
    a later call tries again. At most `size` keys are kept (then all are dropped)."""

    def __init__(self, size: int = 64):
        self.size = size
        self._futures: dict = {}
        self._lock = threading.Lock()

    def get(self, key: Hashable, make: Callable[[], object]) -> tuple[object, bool]:
        """(the value for `key`, whether this call computed it with `make()`)."""
        with self._lock:
            future = self._futures.get(key)
            mine = future is None
            if mine:
                if len(self._futures) >= self.size:
                    self._futures.clear()
                future = self._futures[key] = Future()
        if not mine:
            return future.result(), False
        try:
            value = make()
        except BaseException as e:  # waiters get the error; a later call computes again
            with self._lock:
                self._futures.pop(key, None)
            future.set_exception(e)
            raise
        future.set_result(value)
        return value, True

    def __len__(self) -> int:
        return len(self._futures)

    def clear(self) -> None:
        with self._lock:
            self._futures.clear()


def in_background(work: Callable, name: str) -> Future:
    """`work()` on a daemon thread of its own (an interrupted command does not wait for it): a
    future of its result or its error."""
    future: Future = Future()

    def run() -> None:
        try:
            future.set_result(work())
        except BaseException as e:  # noqa: BLE001 (the future carries it to whoever waits)
            future.set_exception(e)

    threading.Thread(target=run, daemon=True, name=name).start()
    return future
