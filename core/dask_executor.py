"""The heavy stages on a Dask cluster: an :class:`~core.executor.Executor` whose chunks are Dask tasks.

Every heavy loop of the bake is one ``Executor.map_chunks(fn, chunks, progress)`` call
with ``fn`` a closure over the stage's arrays (the scene, a BVH, the texels). Here such a
call becomes:

1. ``fn`` is pickled once (cloudpickle: closures by value, PDIC functions by reference)
   with its large arrays (triangles, texels, photons, records) replaced by content keys:
   each such array is scattered once per executor (a bake) and reaches each worker once,
   fetched from a peer by the first task there that needs it; the rest of the closure
   (kilobytes) once per call. A worker unpickles the closure once per call, and a
   :class:`~core.rays.RayCaster` inside it rebuilds its Embree scene at most once per
   bake and worker process (cached by a digest of the triangles).
2. One task per chunk ships only ``(index, chunk)`` (a slice or a photon batch: about
   a hundred bytes); results come back in chunk order.
3. Progress is reported as tasks finish; a cancel cancels the outstanding tasks within
   :data:`POLL_SECONDS`; a task whose worker dies is re-run elsewhere (Dask's
   scheduler), one that raises is retried :data:`RETRIES` times, and chunks whose
   scattered data died with a worker are re-submitted with the data scattered again.

Each chunk draws its random numbers from a generator seeded by its index, so light maps
do not depend on which worker ran which chunk: they equal the thread pool's bit for bit.

Workers need Python with numpy, scipy, embreex and dask/distributed, not PDIC: the
executor uploads the ``core`` package (a zip under the coordinator's package name) to
every worker, including workers that join or restart later. Dask is imported only when
a :class:`DaskExecutor` is made; the rest of ``core`` never needs it.
"""
from __future__ import annotations

import hashlib
import io
import pickle
import sys
import tempfile
import threading
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .executor import Executor, Progress

MIN_TASKS = 2
"""Calls of fewer chunks run on the coordinator (most hole-record rounds: one small chunk each)."""
RETRIES = 2
"""Re-runs of a chunk that raised on a worker (a lost worker's chunks are re-run by the scheduler)."""
LOST_DATA_RETRIES = 3
"""Times a call's chunks are re-submitted after the cluster lost the data they need (scattered again)."""
_NOT_RUN = object()
"""A chunk's place in map_chunks' results until its result arrives (a chunk may return None)."""
LOST_WORKER_SECONDS = 1.0
"""Wait before scattering again after a worker died mid-scatter (the scheduler removes it on its next check)."""
POLL_SECONDS = 0.05
"""How often the coordinator looks for finished chunks and a cancel request."""
LOCAL_PREFIX = "local:"
"""``local:N`` starts a LocalCluster of N single-thread worker processes on this machine."""
SHARED_ARRAY_BYTES = 64 * 1024
"""Arrays at least this large (triangles, texels, photons, records) go to every worker once per
executor, keyed by content, and closures refer to them by key: a bake ships its geometry once."""
CORE_PACKAGE = __package__
"""The coordinator's name of ``core`` (``pdic.core``, ``bl_ext.<repo>.pdic.core``): workers import it so."""

_loaded_functions: dict[str, Callable] = {}
"""Worker side: the unpickled closures of the current ``map_chunks`` calls, by content key."""
_loaded_lock = threading.Lock()


class DaskUnavailable(RuntimeError):
    """dask/distributed is not installed in this Python, or the scheduler cannot be reached."""


def install_hint() -> str:
    """How to install Dask into the Python running this code (Blender's own, inside Blender)."""
    return f"pip install dask distributed into Blender's Python: {sys.executable} -m pip install dask distributed"


@dataclass(frozen=True)
class Call:
    """One ``map_chunks`` call: the closure's name and task-key prefix, its pickled size without the
    shared arrays (bytes, sent once to every worker), tasks, their pickled arguments (bytes), wall seconds."""

    name: str
    key: str
    closure_bytes: int
    tasks: int
    task_bytes: int
    seconds: float


@dataclass
class Shipping:
    """Bytes the executor sent, summed over its ``map_chunks`` calls.

    array_bytes, arrays : large arrays sent to every worker once (multiply by workers for traffic);
        array_shapes : (dtype, shape) of each.
    scattered_bytes : pickled closures without those arrays, each sent once to every worker.
    task_bytes : pickled ``(index, chunk)`` arguments of every task.
    tasks, calls : tasks submitted, ``map_chunks`` calls made; per_call : a :class:`Call` each, in order.
    local_calls : calls of one chunk, run on the coordinator (:data:`MIN_TASKS`).
    """

    array_bytes: int = 0
    arrays: int = 0
    array_shapes: list = field(default_factory=list)
    scattered_bytes: int = 0
    task_bytes: int = 0
    tasks: int = 0
    calls: int = 0
    local_calls: int = 0
    per_call: list = field(default_factory=list)


class DaskExecutor(Executor):
    """Runs ``map_chunks`` as Dask tasks; plain :meth:`map` (ray batches on the coordinator) stays local.

    Parameters
    ----------
    scheduler : ``tcp://host:port`` (or ``tls://``, ``ws://``) of a running ``dask scheduler``,
        or ``local:N`` for a LocalCluster of N single-thread worker processes here.
    threads : local threads for ray batches traced on the coordinator (1 = its own thread).
    timeout : seconds to wait for the scheduler before giving up.
    """

    in_process = False  # the cluster runs the chunks: a stage beside them would run on the coordinator alone

    def __init__(self, scheduler: str, threads: int = 1, timeout: float = 20.0):
        super().__init__(threads)
        self.scheduler = scheduler
        self.shipping = Shipping()
        self._shared: dict = {}  # content key -> future of a scattered array
        self._cluster = None
        try:
            self.client = self._connect(scheduler, timeout)
            self._upload_core()
        except BaseException:
            self.close()
            raise

    def _connect(self, scheduler: str, timeout: float):
        try:
            from distributed import Client, LocalCluster
        except ImportError as e:
            raise DaskUnavailable(f"scheduler {scheduler!r} needs Dask, which is not installed: "
                                  f"{install_hint()}") from e
        if scheduler.startswith(LOCAL_PREFIX):
            workers = int(scheduler[len(LOCAL_PREFIX):])
            import dask

            # Workers keep the copies of shared arrays their tasks fetched; the active memory manager
            # would drop all but one copy between calls, and a worker dying with it loses the data.
            with dask.config.set({"distributed.scheduler.active-memory-manager.start": False}):
                self._cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                             dashboard_address=":0")  # any free port
            return Client(self._cluster, timeout=timeout)
        try:
            return Client(scheduler, timeout=timeout)
        except OSError as e:
            raise DaskUnavailable(f"cannot reach the Dask scheduler at {scheduler!r} within {timeout:g} s: {e}") from e

    def _upload_core(self):
        """Ship ``core`` as a zip under its coordinator name (the same on every worker that joins later)."""
        blob = core_zip()
        digest = hashlib.blake2b(blob, digest_size=8).hexdigest()
        folder = Path(tempfile.gettempdir()) / f"pdic-core-{digest}"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / "pdic_core.zip"
        if not path.exists():
            path.write_bytes(blob)
        if self._cluster is None:  # a remote scheduler unpickles the tasks too (run_chunk, the chunks)
            self.client.upload_file(str(path))
        else:  # LocalCluster's scheduler runs in this process, where the package is loaded already
            from distributed.diagnostics.plugin import UploadFile

            self.client.register_plugin(UploadFile(str(path)))

    def map_chunks(self, fn: Callable, chunks: list, progress: Progress | None = None) -> list:
        """``fn(index, chunk)`` over ``chunks`` as Dask tasks, results in order (see the module docstring)."""
        if len(chunks) < MIN_TASKS:  # one task runs no faster on a worker than here, and ships nothing here
            self.shipping.local_calls += 1
            return super().map_chunks(fn, chunks, progress)
        start = time.perf_counter()
        from distributed.comm import CommClosedError

        results = [_NOT_RUN] * len(chunks)
        pending = list(range(len(chunks)))

        for attempt in range(LOST_DATA_RETRIES + 1):
            try:
                blob, arrays = self._pickle(fn)
                key = f"pdic-{self.shipping.calls}-{hashlib.blake2b(blob, digest_size=8).hexdigest()}"
                pending = self._run(key, attempt, blob, arrays, chunks, pending, results, progress)
            except CommClosedError:
                # A worker died while the closure or an array was being scattered to it: the
                # scheduler drops it within a heartbeat, and the next attempt scatters to the rest.
                pending = [i for i in pending if results[i] is _NOT_RUN]
                time.sleep(LOST_WORKER_SECONDS)
            if not pending:
                break
            self._forget_lost_arrays()
        else:
            raise DaskUnavailable(f"the Dask cluster at {self.scheduler!r} lost the bake's data "
                                  f"{LOST_DATA_RETRIES + 1} times (its workers keep dying)")
        self._count(fn, key, blob, chunks, time.perf_counter() - start)
        return results  # the shared arrays stay on the workers for the next call, until close()

    def _run(self, key: str, attempt: int, blob: bytes, arrays: dict, chunks: list, pending: list,
             results: list, progress: Progress | None) -> list:
        """Run the ``pending`` chunks into ``results``; returns those whose data the cluster lost.

        A worker that dies holding the only copy of scattered data (the closure or a shared array)
        makes the scheduler cancel every task that needs it: such chunks are returned to be re-run
        after the data is scattered again. Any other error, or a cancel, is raised.
        """
        from distributed import as_completed

        shared = self._scatter(blob)
        suffix = f"-retry{attempt}" if attempt else ""
        futures = [self.client.submit(run_chunk, key, shared, arrays, index, chunks[index],
                                      key=f"{key}{suffix}-{index}", retries=RETRIES) for index in pending]
        position = {f.key: index for f, index in zip(futures, pending)}
        lost = []
        done = len(chunks) - len(pending)
        try:
            finished = as_completed(futures, with_results=True, raise_errors=False)
            remaining = len(futures)
            while remaining:
                batch = finished.next_batch(block=False)
                if not batch:
                    if progress is not None:
                        progress.check()
                    time.sleep(POLL_SECONDS)
                    continue
                for future, result in batch:
                    remaining -= 1
                    if future.status == "cancelled":  # this executor cancels only in the except below
                        lost.append(position[future.key])
                        continue
                    if future.status != "finished":
                        future.result()  # raises the chunk's own error
                    results[position[future.key]] = result
                    done += 1
                if progress is not None:
                    progress.update(done / len(chunks))
        except BaseException:
            self.client.cancel(futures)
            raise
        finally:
            self.client.cancel([shared])
        return sorted(lost)

    def _scatter(self, data):
        """``client.scatter(data)``, a worker lost meanwhile raised as ``CommClosedError`` for ``map_chunks`` to retry.

        A worker killed mid-transfer closes the comm (CommClosedError); one killed before the
        scheduler connects to it makes the scheduler's connect time out, a plain OSError. Chunk
        functions' own OSErrors (a missing file) are not converted: they are not raised here.
        """
        from distributed.comm import CommClosedError

        try:
            return self.client.scatter(data, hash=False)
        except CommClosedError:
            raise
        except OSError as e:
            raise CommClosedError(f"a worker was lost while data was scattered: {e}") from e

    def _forget_lost_arrays(self):
        """Drop the keys of shared arrays the cluster no longer holds, so the next pickle scatters them again."""
        for digest, future in list(self._shared.items()):
            if future.status != "finished":
                del self._shared[digest]

    def _pickle(self, fn: Callable) -> tuple[bytes, dict]:
        """``fn`` pickled with its large arrays replaced by content keys, and {key: scattered array}."""
        import cloudpickle

        used = {}
        share, shared = self._share, self._shared

        class LargeArraysByKey(cloudpickle.Pickler):
            def persistent_id(self, obj):
                if isinstance(obj, np.ndarray) and obj.nbytes >= SHARED_ARRAY_BYTES and not obj.dtype.hasobject:
                    digest = share(obj)
                    used[digest] = shared[digest]
                    return digest
                return None

        out = io.BytesIO()
        LargeArraysByKey(out, protocol=5).dump(fn)
        return out.getvalue(), used

    def _share(self, array: np.ndarray) -> str:
        """The content key of ``array``, scattered the first time it is seen.

        Not broadcast: the scheduler's replication (``broadcast=True``) retries a worker that dies
        during it for ever (distributed 2026.8 keeps the worker set it started with), so the bake
        would hang. Workers fetch the array from a peer on first use and keep their copy.
        """
        array = np.ascontiguousarray(array)
        h = hashlib.blake2b(f"{array.dtype.str}{array.shape}".encode(), digest_size=16)
        h.update(array.reshape(-1).view(np.uint8) if array.size else b"")
        digest = h.hexdigest()
        if digest not in self._shared:
            self._shared[digest] = self._scatter(array)
            self.shipping.array_bytes += array.nbytes
            self.shipping.arrays += 1
            self.shipping.array_shapes.append((array.dtype.str, array.shape))
        return digest

    def _count(self, fn, key: str, blob: bytes, chunks: list, seconds: float):
        import pickle

        task_bytes = sum(len(pickle.dumps((i, c), protocol=5)) for i, c in enumerate(chunks))
        s = self.shipping
        s.scattered_bytes += len(blob)
        s.task_bytes += task_bytes
        s.tasks += len(chunks)
        s.calls += 1
        s.per_call.append(Call(getattr(fn, "__qualname__", "?"), key, len(blob), len(chunks), task_bytes, seconds))

    def close(self):
        for resource in ("client", "_cluster"):
            thing = getattr(self, resource, None)
            if thing is not None:
                setattr(self, resource, None)
                try:
                    thing.close()
                except KeyError:
                    # A local cluster's status watcher may look up a worker that its own bookkeeping dropped
                    # as the workers shut down (dask/distributed#5407, seen with 2026.8 on a loaded machine):
                    # the workers and the scheduler are closed all the same, and the bake's results are in.
                    if resource == "client":
                        raise
        super().close()


def run_chunk(key: str, blob: bytes, arrays: dict, index: int, chunk):
    """Worker side: ``fn(index, chunk)`` with ``fn`` unpickled once per worker and ``map_chunks`` call.

    arrays : {content key: array} the closure refers to, already in this worker's memory.
    """
    with _loaded_lock:
        fn = _loaded_functions.get(key)
        if fn is None:
            _loaded_functions.clear()  # calls run one after another: the previous stage's closure is done
            fn = _loaded_functions[key] = _ArraysFromWorker(io.BytesIO(blob), arrays).load()
    return fn(index, chunk)


class _ArraysFromWorker(pickle.Unpickler):
    def __init__(self, file, arrays: dict):
        super().__init__(file)
        self.arrays = arrays

    def persistent_load(self, digest):
        return self.arrays[digest]


def core_zip() -> bytes:
    """The ``core`` package as a zip importable as :data:`CORE_PACKAGE`, with empty parent packages."""
    here = Path(__file__).resolve().parent
    parts = CORE_PACKAGE.split(".")
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for depth in range(1, len(parts)):
            info = zipfile.ZipInfo("/".join(parts[:depth]) + "/__init__.py", date_time=(2000, 1, 1, 0, 0, 0))
            z.writestr(info, "")
        for source in sorted(here.glob("*.py")):
            info = zipfile.ZipInfo("/".join(parts) + "/" + source.name, date_time=(2000, 1, 1, 0, 0, 0))
            z.writestr(info, source.read_bytes())
    return out.getvalue()
