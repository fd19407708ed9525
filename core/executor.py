"""Where the heavy stages run: a small executor interface over chunks of arrays.

The core's heavy stages (photon batches, record refinement, texel shading)
are pure functions of their chunk of arrays, mapped through an
:class:`Executor`. Here that is a thread pool (embreex and numpy release the
GIL) by default, or a Dask cluster (:class:`core.dask_executor.DaskExecutor`,
chosen by :func:`make_executor`) without touching the stages.

Progress and cancellation also live here: a :class:`Progress` is handed down
the pipeline; stages report fractions and call :meth:`Progress.check` between
chunks, which raises :class:`Cancelled` within one chunk of a cancel request.
"""
from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Callable, Iterable

import numpy as np

TEXEL_CHUNK = 32_768
"""Surface points (texel samples, photons) per chunk: about 0.05-0.5 s of work, so a cancel
is noticed quickly and the chunks of one stage spread over the workers."""


class Executor:
    """Maps a function over items, returning results in order.

    workers : how many run at once (1 = on the calling thread).
    """

    in_process = True
    """Chunks run on this process's cores, so a stage run beside the workers (:class:`Beside`) fills the
    ones they leave idle."""

    def __init__(self, workers: int = 1):
        self.workers = max(1, int(workers))
        self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="pdic") if self.workers > 1 else None

    def map(self, fn: Callable, items: Iterable) -> list:
        if self._pool is None:
            return [fn(item) for item in items]
        return list(self._pool.map(fn, items))

    def map_chunks(self, fn: Callable, chunks: list, progress: "Progress | None" = None) -> list:
        """The one chunk loop of the bake: ``fn(index, chunk)`` over ``chunks`` (slices, batches),
        results in order, reporting progress (and noticing a cancel) after each chunk.
        ``index`` is the chunk's position, which seeds its random stream."""
        return map_chunks(self, fn, chunks, progress)

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def make_executor(threads: int = 0, scheduler: str = "") -> Executor:
    """The bake's executor: a pool of ``threads`` (0 = all cores) or, given a ``scheduler`` address
    (``tcp://host:port``, ``local:N``), a :class:`core.dask_executor.DaskExecutor` whose coordinator
    traces its own ray batches on ``threads``. Raises ``DaskUnavailable`` (a RuntimeError) with the
    install command or the unreachable address."""
    threads = threads or default_workers()
    if not scheduler:
        return Executor(threads)
    from .dask_executor import DaskExecutor  # Dask is optional: imported only when asked for

    return DaskExecutor(scheduler, threads)


def serial_executor() -> Executor:
    return Executor(1)


def default_workers() -> int:
    """All cores the process may use (2 on the reference machine)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


class Cancelled(Exception):
    """Raised inside the pipeline when the user cancelled the bake."""


class Progress:
    """Thread-safe stage/fraction reporting with cancellation.

    ``callback(stage, fraction, eta_seconds)`` is called on every report (from
    worker threads too); ``eta_seconds`` is None until a stage has run long
    enough to extrapolate. Set :attr:`cancel_requested` (or call
    :meth:`cancel`) from any thread; the pipeline raises :class:`Cancelled` at
    its next :meth:`check`.
    """

    def __init__(self, callback: Callable[[str, float, float | None], None] | None = None):
        self.callback = callback
        self.cancel_requested = threading.Event()
        self.stage = ""
        self.target = ""
        """The object whose texels the stage works on (:meth:`naming`), reported before the stage."""
        self.fraction = 0.0
        self._stage_start = time.perf_counter()
        self._lock = threading.Lock()

    def cancel(self):
        self.cancel_requested.set()

    def check(self):
        if self.cancel_requested.is_set():
            raise Cancelled("bake cancelled")

    def begin(self, stage: str):
        with self._lock:
            self.stage, self.fraction = stage, 0.0
            self._stage_start = time.perf_counter()
        self._emit(None)
        self.check()

    def update(self, fraction: float):
        with self._lock:
            self.fraction = min(max(float(fraction), 0.0), 1.0)
            elapsed = time.perf_counter() - self._stage_start
            eta = elapsed * (1.0 - self.fraction) / self.fraction if self.fraction > 0.02 and elapsed > 0.5 else None
        self._emit(eta)
        self.check()

    @contextmanager
    def naming(self, target: str):
        """Report the stages inside the block as ``"<target>: <stage>"``: a scene of many objects runs the
        per-object stages once per object, and the label says whose turn it is. ``stage`` stays the bare
        name (stages build their sub-stages' labels from it)."""
        self.target = target
        try:
            yield
        finally:
            self.target = ""

    def _emit(self, eta):
        if self.callback is not None:
            self.callback(f"{self.target}: {self.stage}" if self.target else self.stage, self.fraction, eta)


class Beside:
    """``fn()`` on a thread of its own while the calling thread goes on: a stage that needs neither the
    caller's results nor its workers, run where they leave a core idle (the serial stretches of pass 2).

    ``progress`` is the side's own (silent) :class:`Progress`; :meth:`wait` passes ``watch``'s cancel on
    to it while waiting. :meth:`start` starts it (:meth:`wait` does if nothing did); :meth:`stop` asks
    it to stop at its next chunk and waits for it.
    """

    def __init__(self, fn: Callable[[], None], progress: Progress, watch: Progress):
        self.progress, self.watch = progress, watch
        self._error: list[BaseException] = []

        def run():
            try:
                fn()
            except BaseException as e:  # re-raised on the calling thread by wait()
                self._error.append(e)

        self._thread = threading.Thread(target=run, name="pdic-beside", daemon=True)

    def start(self) -> None:
        if not self.started:
            self._thread.start()

    @property
    def started(self) -> bool:
        return self._thread.ident is not None

    @property
    def running(self) -> bool:
        """Started and not finished: waiting for it would block."""
        return self._thread.is_alive()

    def wait(self) -> None:
        """Join the side; raises its error, or Cancelled once the watched progress is cancelled."""
        self.start()
        while self._thread.is_alive():
            self._thread.join(0.05)
            if self.watch.cancel_requested.is_set():
                self.stop()
        if self._error:
            raise self._error[0]
        self.watch.check()

    def stop(self) -> None:
        self.progress.cancel()
        if self.started:
            self._thread.join()


def slices(n: int, size: int) -> list[slice]:
    """Consecutive slices of ``range(n)`` of at most ``size`` items."""
    return [slice(s, min(s + size, n)) for s in range(0, n, size)]


ROW_CHUNK = 65_536
"""Rows per pass of a row-wise numpy computation over millions of rows (texel samples, photons, zone-grid
entries): its temporaries, a few MB, come from memory the allocator reuses, where whole-array ones (hundreds
of MB) are fresh pages on every call, mapped, faulted and zeroed by the kernel: Sponza 16 texels/m's sheet
test over its 5.2 M samples took 3.6-4.0 s that way, 3.1-3.5 s of it in the kernel, and 0.39 s in passes of
this many rows; a zone grid over 94k hole records 0.36-0.53 s, and 0.06 s."""


def row_chunks(n: int) -> list[slice]:
    """:func:`slices` of ``range(n)`` in ROW_CHUNK rows."""
    return slices(n, ROW_CHUNK)


def group_chunks(first: np.ndarray, n: int) -> list[slice]:
    """Slices of ``range(n)``, in order, that keep groups whole: rows in groups starting at ``first`` (g,)
    increasing, first[0] = 0; each cut at the first group start at or after a multiple of ROW_CHUNK (a slice
    holds one group longer than that whole, and may be shorter). A group's sums over its rows (np.bincount)
    are then made in one pass, in its rows' order, as over all rows at once."""
    cuts = np.append(first, n)
    ends = cuts[np.searchsorted(cuts, np.arange(ROW_CHUNK, n, ROW_CHUNK))]
    bounds = np.unique(np.concatenate([[0], ends, [n]]))
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def map_chunks(executor: "Executor", fn: Callable, chunks: list, progress: "Progress | None" = None) -> list:
    """``fn(index, chunk)`` over ``chunks`` on ``executor``, results in order; reports the done
    fraction to ``progress`` after every chunk (where a cancel is noticed)."""
    lock = threading.Lock()
    done = [0]

    def run(job):
        index, chunk = job
        out = fn(index, chunk)
        if progress is not None:
            with lock:
                done[0] += 1
                fraction = done[0] / len(chunks)
            progress.update(fraction)
        return out

    return executor.map(run, list(enumerate(chunks)))
