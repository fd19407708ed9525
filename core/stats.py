"""Run statistics: per-pass wall times and work counters, JSON-ready.

The manifest's ``stats`` block is :meth:`BakeStats.as_dict`; its keys are
documented in ``core/manifest.py`` and must stay stable.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field


@dataclass
class BakeStats:
    seconds: dict = field(default_factory=dict)
    """Wall seconds per named stage, in the order they ran."""
    counters: dict = field(default_factory=dict)
    """Work counters (photons, records, rays cast and saved, texels, ...), integers or floats."""

    @contextmanager
    def stage(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start

    def add(self, **counters):
        for key, value in counters.items():
            self.counters[key] = self.counters.get(key, 0) + value

    def set(self, **counters):
        self.counters.update(counters)

    def as_dict(self) -> dict:
        total = sum(self.seconds.values())
        return {
            "seconds": {k: round(v, 4) for k, v in self.seconds.items()},
            "seconds_total": round(total, 4),
            "counters": {k: (int(v) if float(v).is_integer() else float(v)) for k, v in self.counters.items()},
        }
