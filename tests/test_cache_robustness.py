"""Caches only save time: a damaged, foreign or unwritable cache never fails a bake nor is used."""
from __future__ import annotations

import numpy as np
import pytest
from test_unwrap import quad_grid, wavy

from pdic.core.bake_cache import BakeCache
from pdic.core.cache_files import read_entry, write_entry
from pdic.core.irradiance_cache import IrradianceCache
from pdic.core.unwrap import unwrap


def _unwrap_file(tmp_path):
    p, t, poly, _ = quad_grid(6, wavy)
    first = unwrap(p, t, 64, 2, tmp_path, poly)
    (path,) = tmp_path.glob("unwrap-*.npz")
    return (p, t, poly), first, path


def _flip_byte(path, where=0.5):
    data = bytearray(path.read_bytes())
    data[int(len(data) * where)] ^= 0x10
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["truncated", "empty", "flipped"])
def test_damaged_unwrap_cache_file_is_recomputed(tmp_path, damage):
    args, first, path = _unwrap_file(tmp_path)
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    else:
        _flip_byte(path)
    again = unwrap(*args[:2], 64, 2, tmp_path, args[2])
    assert not again.from_cache and np.array_equal(again.uv, first.uv)
    assert unwrap(*args[:2], 64, 2, tmp_path, args[2]).from_cache  # rewritten, good again


def test_unwrap_cache_entry_with_overlapping_uvs_is_not_used(tmp_path):
    """A well-formed entry (checksum right) whose UVs overlap is recomputed, not baked."""
    args, first, path = _unwrap_file(tmp_path)
    header, arrays = read_entry(path)
    arrays["uv"] = np.broadcast_to(arrays["uv"][:1], arrays["uv"].shape).copy()  # every triangle on one spot
    write_entry(path, header, arrays)
    again = unwrap(*args[:2], 64, 2, tmp_path, args[2])
    assert not again.from_cache and np.array_equal(again.uv, first.uv)


def test_unwritable_unwrap_cache_folder_unwraps_with_a_warning(tmp_path):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where the cache folder should be")
    p, t, poly, _ = quad_grid(4, wavy)
    r = unwrap(p, t, 64, 2, blocker / "cache", poly)
    assert r.uv.shape == (len(t), 3, 2) and len(r.warnings) == 1
    assert "cannot be written" in r.warnings[0] and "not_a_folder" in r.warnings[0]


def _records():
    rng = np.random.default_rng(3)
    k = 5
    return IrradianceCache(p=rng.random((k, 3)), n=np.tile([0.0, 0.0, 1.0], (k, 1)), E=rng.random((k, 3)),
                           R=rng.random(k) + 0.1, grad_r=np.zeros((k, 3, 3)), grad_t=np.zeros((k, 3, 3)),
                           photons_used=np.full(k, 9, np.int32), hole=np.zeros(k, bool), refined=np.zeros(k, bool))


def test_bake_cache_round_trips_dataclasses_through_disk_without_pickle(tmp_path):
    value = (_records(), {"E": np.arange(3.0)}, 7, slice(2, 9))
    key = BakeCache(tmp_path).key("cache", "scene")
    BakeCache(tmp_path).put("cache", key, value)
    (path,) = tmp_path.glob("cache-*.npz")
    with np.load(path, allow_pickle=False) as data:  # plain arrays: nothing runs on load
        assert all(data[name].dtype != object for name in data.files)
    back = BakeCache(tmp_path).get("cache", key)
    assert isinstance(back[0], IrradianceCache) and back[2] == 7 and back[3] == slice(2, 9)
    for name in ("p", "E", "R", "photons_used", "hole", "wall"):
        assert np.array_equal(getattr(back[0], name), getattr(value[0], name))
    assert np.array_equal(back[1]["E"], value[1]["E"])


@pytest.mark.parametrize("damage", ["flipped", "nan"])
def test_damaged_bake_cache_entry_is_a_miss(tmp_path, damage):
    store = BakeCache(tmp_path, memory=False)
    key = store.key("direct", "target")
    store.put("direct", key, np.ones((4, 4, 3)))
    (path,) = tmp_path.glob("direct-*.npz")
    data = bytearray(path.read_bytes())
    at = bytes(data).index(np.ones((4, 4, 3)).tobytes())  # the stored array, checksum left as it was
    if damage == "flipped":
        data[at + 13] ^= 0x10
    else:
        data[at:at + 8] = np.float64(np.nan).tobytes()
    path.write_bytes(bytes(data))
    assert store.get("direct", key) is None and store.misses["direct"] == 1


def test_unwritable_bake_cache_folder_keeps_values_in_memory_and_warns(tmp_path):
    blocker = tmp_path / "full"
    blocker.write_text("")
    store = BakeCache(blocker / "cache")
    key = store.key("photons", "scene")
    store.put("photons", key, np.arange(5.0))  # no OSError escapes
    store.put("photons", store.key("photons", "other"), np.arange(2.0))
    assert np.array_equal(store.get("photons", key), np.arange(5.0))
    assert len(store.warnings) == 1 and "cannot be written" in store.warnings[0]


def test_no_bake_cache_entry_of_other_code_is_reused(tmp_path):
    """Every kind, the texel samples too, is keyed by the core's code: after an update (here: another
    code hash) a bake recomputes all, and with the same code it reuses all."""
    from scenes import lamp_box

    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    settings = preset("PREVIEW", photons=2000, max_bounces=2, threads=1)
    bake(lamp_box(8), settings, cache=BakeCache(tmp_path))
    same = BakeCache(tmp_path, memory=False)
    bake(lamp_box(8), settings, cache=same)
    assert same.hits["raster"] > 0 and sum(same.misses.values()) == 0
    updated = BakeCache(tmp_path, memory=False)
    updated.code = "another version of core/"
    bake(lamp_box(8), settings, cache=updated)
    assert sum(updated.hits.values()) == 0 and updated.misses["raster"] > 0
