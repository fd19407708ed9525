"""Shared test set-up: the repo as package ``pdic``, a clean Blender around every bpy test."""
from __future__ import annotations

import faulthandler
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()

SHARED = ROOT.parent / "shared"
HANG_SECONDS = 900
"""A test still running after this long is hung (the slowest takes about two minutes): print every
thread's stack and end the run, so CI reports where it stuck instead of running into its time limit."""


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes tens of seconds (millions of photons, Cycles references, "
                                       "whole-scene bakes); skip with -m 'not slow' while iterating")
SCENES = SHARED / "scenes"


@pytest.fixture(autouse=True)
def hang_guard():
    faulthandler.dump_traceback_later(HANG_SECONDS, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    """Each test gets its own cache folder: no unwrap or bake-cache entry leaks between tests or runs."""
    monkeypatch.setenv("PDIC_CACHE_DIR", str(tmp_path / "pdic_cache"))


@pytest.fixture
def blender():
    """A factory-fresh Blender (bpy wheel), reset again after the test."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)


@pytest.fixture(scope="module")
def registered():
    """The add-on registered for a test module, and cleanly unregistered after it."""
    import bpy

    from pdic import pdic_addon

    pdic_addon.register()
    yield
    pdic_addon.unregister()
    assert not hasattr(bpy.types.Scene, "pdic")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)
