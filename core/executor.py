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


class HelpedExecutor(Executor):
    """One worker, the calling thread, that another thread may help: a stage run beside the bake
    (:class:`Beside`) maps its chunks here, and the bake's thread, once it has nothing left to do but wait for
    that stage, takes chunks of it too (:meth:`help`) instead of leaving its core idle (Sponza at 2048^2,
    Preview: 13-14 s of texel validity waited for so; the building lit by 64 lamps, Preview: 8.7 s of direct
    light). A chunk computes the same whichever thread runs it (its random stream is its index's, its
    results are kept in order), so the bake is the same to the bit. A map inside a chunk runs on its
    caller's thread, unhelped."""

    def __init__(self):
        super().__init__(1)
        self._job: _SharedJob | None = None
        self._lock = threading.Lock()

    def map(self, fn: Callable, items: Iterable) -> list:
        job = _SharedJob(fn, list(items))
        with self._lock:
            nested, self._job = self._job is not None, self._job or job
        if nested:
            return [fn(item) for item in job.items]
        try:
            while job.run_next():
                pass
            return job.results()
        finally:
            with self._lock:
                self._job = None

    def help(self) -> bool:
        """Run one item of the map under way, if any is left; False when there is none to take."""
        with self._lock:
            job = self._job
        return job is not None and job.run_next()


class _SharedJob:
    """The items of one :meth:`HelpedExecutor.map`, taken one at a time by whichever thread asks next."""

    def __init__(self, fn: Callable, items: list):
        self.fn, self.items = fn, items
        self._out = [None] * len(items)
        self._next, self._running = 0, 0
        self._error: BaseException | None = None
        self._cond = threading.Condition()

    def run_next(self) -> bool:
        """Run the next item on this thread; False when none is left (or an item failed)."""
        with self._cond:
            if self._next >= len(self.items) or self._error is not None:
                return False
            index = self._next
            self._next += 1
            self._running += 1
        try:
            self._out[index] = self.fn(self.items[index])
        except BaseException as e:  # raised by the map's own thread (results); a helper goes on
            with self._cond:
                self._error = self._error or e
            if not isinstance(e, Exception):  # an interrupt stops the thread it reached too
                raise
        finally:
            with self._cond:
                self._running -= 1
                self._cond.notify_all()
        return True

    def results(self) -> list:
        """The items' results in order, once the helpers' last items are done; the first error raised."""
        with self._cond:
            while self._running:
                self._cond.wait()
        if self._error is not None:
            raise self._error
        return self._out


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

    def wait(self, help: Callable[[], bool] | None = None) -> None:
        """Join the side; raises its error, or Cancelled once the watched progress is cancelled.

        help : what the waiting thread does meanwhile, a piece at a time (:meth:`HelpedExecutor.help`); it
        returns False when there is nothing to do."""
        self.start()
        while self._thread.is_alive():
            if help is None or not help():
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
