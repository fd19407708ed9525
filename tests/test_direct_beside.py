"""The direct light runs beside passes 2-3, and texel validity beside pass 2, each on a thread of its own
(issue 12: pass 2's serial stretches leave a core idle). They must compute what they compute in line, count
what they cast, stop with the bake and pass their errors on."""
import threading
import time

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.executor import Beside, Cancelled, Progress
from pdic.core.pipeline import bake
from pdic.core.settings import preset

from scenes import box_on_ground, lamp_box

FINAL = dict(photons=4000, max_bounces=3, hemisphere_theta=6, hemisphere_phi=12)


def _beside_threads() -> list:
    return [t for t in threading.enumerate() if t.name == "pdic-beside"]


@pytest.mark.parametrize("threads", [1, 2])
def test_the_direct_light_beside_passes_2_and_3_is_the_direct_light_in_line(threads):
    scene = lamp_box(16)
    beside = bake(scene, preset("FINAL", threads=threads, **FINAL))
    in_line = bake(scene, preset("FINAL", threads=threads, indirect=False, **FINAL))
    for name in in_line.direct:
        assert in_line.direct[name].max() > 0
        assert np.array_equal(beside.direct[name], in_line.direct[name]), name
    a, b = beside.stats["counters"], in_line.stats["counters"]
    assert a["shadow_rays"] == b["shadow_rays"] > 0
    assert a["targets_shaded_direct"] == b["targets_shaded_direct"] == 2
    # its rays join the bake's count: the direct light's and those of passes 1-3, each cast once
    assert a["rays_cast"] > a["shadow_rays"] + a["refine_rays_cast"]
    seconds = beside.stats["seconds"]
    assert "direct" in seconds
    if threads > 1:  # its time overlaps passes 2-3: listed, not summed (what the bake waited for it is)
        # texel validity beside pass 2 too, and the smaller target's texels beside the larger's
        assert beside.stats["seconds_beside"] == ["direct", "texels", "validity"]
        assert beside.stats["seconds_total"] == pytest.approx(
            sum(v for k, v in seconds.items() if k not in ("direct", "texels", "validity")), abs=1e-3)
        assert 0.0 < beside.stats["counters"]["embree_share_direct"] <= 1.0
    else:  # one thread: in line, as before
        assert "seconds_beside" not in beside.stats
    assert not _beside_threads()


def test_with_passes_2_and_3_stored_the_direct_light_runs_in_line_on_the_bakes_workers(tmp_path):
    """Nothing runs beside it then: a re-bake that changes only the direct light's samples reads passes
    1-3 and the texels' indirect light from the bake cache, and shades in line as a bake without
    indirect light does, not on one thread while the workers wait."""
    from pdic.core.bake_cache import BakeCache

    scene, store = lamp_box(16), BakeCache(tmp_path)
    bake(scene, preset("FINAL", threads=2, **FINAL), cache=store)
    again = bake(scene, preset("FINAL", threads=2, direct_samples=2, **FINAL), cache=store)
    in_line = bake(scene, preset("FINAL", threads=2, direct_samples=2, indirect=False, **FINAL))
    c = again.stats["counters"]
    # the store's counts over both bakes: the second read the texels' indirect light, shaded both targets again
    assert c["cache_hits_indirect"] == 2 and c["cache_misses_direct"] == 4 and c["targets_shaded_direct"] == 2
    assert "seconds_beside" not in again.stats and "direct_wait" not in again.stats["seconds"]
    for name in in_line.direct:
        assert np.array_equal(again.direct[name], in_line.direct[name]), name
    assert not _beside_threads()


def test_a_cancel_during_pass_2_stops_the_direct_light_beside_it():
    progress = Progress(lambda stage, fraction, eta: progress.cancel() if stage.startswith("Pass 2") else None)
    with pytest.raises(Cancelled):
        bake(lamp_box(48), preset("FINAL", threads=2, **FINAL), progress)
    assert not _beside_threads()


def test_the_texels_stage_beside_the_direct_light_computes_and_counts_what_it_does_in_line():
    """The first target's texels' stage starts while the direct light may still run on its thread; both
    test samples on touching faces (deviation: contact-faces), each on a view of the tests of its own: the
    same maps and the same count of those tests' rays as a bake with everything in line on one thread."""
    scene = box_on_ground()
    two, one = (bake(scene, preset("FINAL", threads=threads, **FINAL)) for threads in (2, 1))
    assert two.stats["seconds_beside"][:1] == ["direct"] and "validity" in two.stats["seconds_beside"]
    for name in one.direct:
        assert np.array_equal(two.direct[name], one.direct[name]), name
        assert np.array_equal(two.indirect[name], one.indirect[name]), name
    a, b = two.stats["counters"], one.stats["counters"]
    assert a["contact_rays"] == b["contact_rays"] > a["texel_samples_in_contact"] > 0
    # texel validity and the crevice test ran beside pass 2 on two threads, in line on one: the same verdicts
    for key in ("texel_samples_inside_geometry", "texel_samples_covered", "validity_rays", "crevice_samples",
                "crevice_distance_rays", "rays_cast"):
        assert a[key] == b[key], key
    assert a["texel_samples_inside_geometry"] > 0 and a["crevice_samples"] > 0


def test_a_cancel_during_the_texels_stage_stops_the_direct_light_beside_it():
    progress = Progress(lambda stage, fraction, eta: progress.cancel() if "Texel validity" in stage
                        or "Interpolating" in stage else None)
    with pytest.raises(Cancelled):
        bake(lamp_box(48), preset("FINAL", threads=2, **FINAL), progress)
    assert not _beside_threads()


def test_an_error_beside_reaches_the_caller_when_it_waits():
    def fail():
        raise ValueError("bad light")

    beside = Beside(fail, Progress(), Progress())
    with pytest.raises(ValueError, match="bad light"):
        beside.wait()


def test_a_cancel_of_the_watched_progress_stops_the_side_at_its_next_check():
    side, watch = Progress(), Progress()
    checks = []

    def work():
        while True:
            checks.append(1)
            side.check()
            time.sleep(0.001)

    beside = Beside(work, side, watch)
    watch.cancel()
    with pytest.raises(Cancelled):
        beside.wait()
    assert checks and not _beside_threads()


def test_the_smaller_targets_texels_beside_the_larger_give_the_light_and_counts_of_one_thread():
    """With two workers the smallest targets' texels' stages run on a thread beside the bake's (a scene of
    many small objects ran each on one core): every map, and every work counter, as on one thread."""
    scene = lamp_box(16)  # two targets, the floor and the back wall
    small = replace(scene, targets=(scene.targets[0], replace(scene.targets[1], width=8, height=8)))
    two, one = (bake(small, preset("FINAL", threads=threads, **FINAL)) for threads in (2, 1))
    assert "texels" in two.stats["seconds_beside"] and "texels" not in one.stats["seconds"]
    for name in one.lightmaps:
        assert one.indirect[name].max() > 0
        assert np.array_equal(two.lightmaps[name], one.lightmaps[name]), name
    a, b = two.stats["counters"], one.stats["counters"]
    assert a["targets_shaded_indirect"] == b["targets_shaded_indirect"] == 2
    for key in b:
        if not key.startswith("embree_"):
            assert a[key] == b[key], key
    assert a["hole_records"] > 0 and a["texel_points_interpolated"] > 0
    assert not _beside_threads()
