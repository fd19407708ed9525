"""Run statistics: per-pass wall times and work counters, JSON-ready.

The manifest's ``stats`` block is :meth:`BakeStats.as_dict`; its keys are
documented in ``core/manifest.py`` and must stay stable.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field

from . import native_kernels


@dataclass
class BakeStats:
    seconds: dict = field(default_factory=dict)
    """Wall seconds per named stage, in the order they ran."""
    counters: dict = field(default_factory=dict)
    """Work counters (photons, records, rays cast and saved, texels, ...), integers or floats."""
    workers: int = 1
    """Threads the stages run on: a stage's thread time is ``workers`` x its wall seconds."""
    clock: object = None
    """The ray caster's :class:`~core.rays.EmbreeClock` once a BVH exists (None before)."""
    embree_seconds: dict = field(default_factory=dict)
    """Seconds inside Embree per stage, summed over threads (read from :attr:`clock`)."""
    beside: dict = field(default_factory=dict)
    """Stages that ran on a thread of their own beside the others (:meth:`fold`) -> the threads they ran on."""

    @contextmanager
    def stage(self, name: str):
        start = time.perf_counter()
        embree_start = self._embree_reading()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
            if self.clock is not None:
                spent = self._embree_reading() - embree_start
                self.embree_seconds[name] = self.embree_seconds.get(name, 0.0) + spent

    def _embree_reading(self) -> float:
        return self.clock.seconds if self.clock is not None else 0.0

    def fold(self, other: "BakeStats") -> None:
        """Take in the statistics of a stage that ran beside this run's (its own thread, clock and
        counters): its wall seconds overlap other stages' (listed, left out of ``seconds_total``)."""
        for name, seconds in other.seconds.items():
            self.seconds[name] = self.seconds.get(name, 0.0) + seconds
            self.beside[name] = other.workers
        for name, seconds in other.embree_seconds.items():
            self.embree_seconds[name] = self.embree_seconds.get(name, 0.0) + seconds
        self.add(**other.counters)

    def add(self, **counters):
        for key, value in counters.items():
            self.counters[key] = self.counters.get(key, 0) + value

    def set(self, **counters):
        self.counters.update(counters)

    def embree_counters(self) -> dict:
        """``embree_seconds_<stage>`` and ``embree_share_<stage>`` (in [0, 1]) for every stage that cast rays.

        The share is Embree's part of the stage's thread time: summed seconds inside Embree over
        ``workers`` x wall seconds (threads idle or running other stages count as not-Embree; a stage
        that ran beside others, on one thread: that thread's wall seconds).
        """
        out = {}
        for name, spent in self.embree_seconds.items():
            wall = self.seconds.get(name, 0.0)
            if spent <= 0.0 or wall <= 0.0:
                continue
            out[f"embree_seconds_{name}"] = float(f"{spent:.6g}")  # a tiny stage stays above 0
            threads = self.beside.get(name, self.workers)
            out[f"embree_share_{name}"] = min(spent / (wall * max(threads, 1)), 1.0)
        return out

    def as_dict(self) -> dict:
        # A stage that ran beside others overlaps their time; what the bake waited for it is its own stage.
        total = sum(v for k, v in self.seconds.items() if k not in self.beside)
        counters = {**self.counters, **self.embree_counters()}
        out = {
            "seconds": {k: round(v, 4) for k, v in self.seconds.items()},
            "seconds_total": round(total, 4),
            "counters": {k: (int(v) if float(v).is_integer() else float(v)) for k, v in counters.items()},
            "kernels": native_kernels.status(),
        }
        if self.beside:
            out["seconds_beside"] = sorted(self.beside)
        return out
