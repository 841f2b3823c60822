"""A live Rerun stream's calls, run in a thread of their own so that a viewer which stops taking data never stops
the rig.

rerun's gRPC sink blocks the logging call once its channels are full: a viewer that accepted the connection and then
took no data (frozen, suspended) froze a fast node 30 s into its run, inside ``send_columns``, where neither its
Ctrl-C nor its recording could be finished. Here the caller only queues its calls; a job that finds the queue full
is dropped and counted (the bag keeps every reading, the viewer shows a gap).
"""

from __future__ import annotations

import functools
import queue
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

#: jobs (a public logging method's calls each) waiting for the viewer: ~10 s of a node's 0.1 s batches
MAX_QUEUED_JOBS = 100

F = TypeVar("F", bound=Callable[..., Any])


class QueuedStream:
    """Stands for a ``rerun.RecordingStream``: each call is queued and made, in order, by a daemon thread. Calls
    made inside :meth:`job` go as one job (a ``set_time`` is never separated from the ``log`` it dates)."""

    def __init__(self, rec: Any, max_jobs: int = MAX_QUEUED_JOBS) -> None:
        self.rec = rec
        self.offered = 0  # jobs the caller queued or tried to
        self.dropped = 0  # jobs dropped because the queue was full
        self.errors: list[str] = []  # the first error rerun raised in the thread (further ones are not kept)
        self._jobs: queue.Queue[list[tuple[Callable[..., Any], tuple, dict]] | None] = queue.Queue(max_jobs)
        self._group: list[tuple[Callable[..., Any], tuple, dict]] | None = None
        self._thread = threading.Thread(target=self._run, name="rerun-sender", daemon=True)
        self._thread.start()

    @property
    def in_job(self) -> bool:
        return self._group is not None

    @contextmanager
    def job(self) -> Iterator[None]:
        """The calls made in the block, queued as one job when it ends."""
        self._group = []
        try:
            yield
        finally:
            calls, self._group = self._group, None
            if calls:
                self._put(calls)

    def __getattr__(self, name: str) -> Callable[..., None]:
        method = getattr(self.rec, name)

        def queued(*args: Any, **kwargs: Any) -> None:
            if self._group is not None:
                self._group.append((method, args, kwargs))
            else:
                self._put([(method, args, kwargs)])

        return queued

    def _put(self, calls: list[tuple[Callable[..., Any], tuple, dict]]) -> None:
        self.offered += 1
        try:
            self._jobs.put_nowait(calls)
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while True:
            calls = self._jobs.get()
            if calls is None:
                return
            for method, args, kwargs in calls:
                try:
                    method(*args, **kwargs)
                except Exception as exc:  # noqa: BLE001 - rerun's errors, reported by the logger's close
                    if not self.errors:
                        self.errors.append(f"{type(exc).__name__}: {exc}")

    def drain(self, timeout_s: float) -> bool:
        """Stop taking jobs and wait up to ``timeout_s`` (wall) for the queued ones to be made: True when they all
        were."""
        deadline = time.monotonic() + timeout_s
        try:
            self._jobs.put(None, timeout=timeout_s)
        except queue.Full:
            return False
        self._thread.join(max(0.0, deadline - time.monotonic()))
        return not self._thread.is_alive()


def one_job(method: F) -> F:
    """A logging method whose stream calls go to a :class:`QueuedStream` as one job (a nested call joins the
    caller's job). Unchanged for a stream written in the caller's thread (a file)."""

    @functools.wraps(method)
    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        rec = self._rec
        if not isinstance(rec, QueuedStream) or rec.in_job:
            return method(self, *args, **kwargs)
        with rec.job():
            return method(self, *args, **kwargs)

    return wrapper  # type: ignore[return-value]
