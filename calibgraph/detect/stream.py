"""Detection jobs on worker threads, fed as a stream and answered in the order they were given.

OpenCV releases the GIL while it decodes and searches, so threads detect in parallel. A dataset
driver submits jobs as it learns what to look for (a survey of the first frames, then searches
guided by a pose estimate) and keeps up to ``lookahead`` jobs in flight, so that every worker has
a frame from the first to the last: there is no batch whose slowest frame idles the other cores.
Answers come back in submission order, so a driver's decisions (and so its results) depend on
the answers, never on which thread happened to finish first.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor


def _one_opencv_thread():
    import cv2

    cv2.setNumThreads(1)  # parallelism comes from the pool; OpenCV's own threads would oversubscribe


class OrderedPool:
    """A thread pool whose results are taken in submission order (module docstring).

    Use as a context manager; leaving it on an exception cancels the jobs not yet started.
    """

    def __init__(self, workers: int = 2, lookahead: int | None = None):
        self.workers = max(1, int(workers))
        self.lookahead = lookahead or 4 * self.workers
        self._ex = ThreadPoolExecutor(max_workers=self.workers, initializer=_one_opencv_thread)
        self._queue = deque()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self._ex.shutdown(wait=True, cancel_futures=exc_type is not None)
        return False

    def __len__(self) -> int:
        return len(self._queue)

    @property
    def has_room(self) -> bool:
        """Fewer than ``lookahead`` jobs are waiting to be taken."""
        return len(self._queue) < self.lookahead

    def submit(self, key, fn, *args) -> None:
        """Run ``fn(*args)`` on a worker; its result is taken with ``key`` by :meth:`next`."""
        self._queue.append((key, self._ex.submit(fn, *args)))

    def put(self, key, value) -> None:
        """Queue an answer known already (a cache hit) in its place in the order."""
        f = Future()
        f.set_result(value)
        self._queue.append((key, f))

    def next(self, waiting=None, poll_s: float = 1.0):
        """(key, result) of the oldest job, waiting for it if needed; raises what the job raised.
        ``waiting``: called every ``poll_s`` seconds while it waits (a pass's progress lines)."""
        from concurrent.futures import TimeoutError as Pending

        key, f = self._queue[0]
        while waiting is not None:
            try:
                f.result(timeout=poll_s)
                break
            except Pending:
                waiting()
            except BaseException:
                break  # raised again below
        self._queue.popleft()
        return key, f.result()
