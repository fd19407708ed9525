"""Texel samples read from records far off get hole records of their own (deviation: thin-coverage).

A sample that one record accepts near its zone's edge reads that record's E_k from up to a R_k
away: on Sponza's upper arches a moulding's sample read a single record 9 cm off where the light
halves every 9 cm (E/pi 0.21 against a path tracer's 0.11). At Final, samples whose accepted weights
sum below THIN_COVERAGE / a are holes too in the first round; Equation 3 at them then runs over the
old records and the new.
"""
from types import SimpleNamespace

import numpy as np

from pdic.core.constants import THIN_COVERAGE
from pdic.core.density import PhotonDensity
from pdic.core.executor import Executor, Progress
from pdic.core.hole_records import fill_holes
from pdic.core.interpolation import CacheLookup
from pdic.core.irradiance_cache import CacheParameters, cache_from_photons
from pdic.core.photons import trace_photons
from pdic.core.rays import RayCaster
from pdic.core.refinement import gather_sources
from pdic.core.scene import PointLight
from pdic.core.settings import Deviations, preset

from scenes import lit, quad

PARAMS = CacheParameters(a=0.4, r_nearest=16, R_min=0.02, R_max=1.0, neighbour_clamp=True)


def _fill(thin: bool):
    """A floor with a wall on it, lit from above: pass 2's records, then Final's hole filling (standard
    gathering over a coarse hemisphere, no hit grid; one round, so every new record is the thin
    coverage's or the holes') at a grid of samples on the floor. (filled, the
    samples (m, 3), their normals, the records' weights sum at each sample before any hole record)."""
    tris = np.concatenate([quad([-1, -1, 0], [2, 0, 0], [0, 2, 0]), quad([0.3, -1, 0], [0, 2, 0], [0, 0, 1])])
    scene = lit(tris, PointLight("p", np.array([-0.3, 0.0, 0.8]), np.full(3, 100.0)))
    caster = RayCaster(tris)
    photons, _ = trace_photons(scene, caster, 20_000, 3, seed=3)
    density = PhotonDensity(photons)
    cache, _, lighting, _ = cache_from_photons(density, PARAMS, seed=1, caster=caster)
    x, y = np.meshgrid(np.linspace(-0.98, 0.28, 64), np.linspace(-0.98, 0.98, 96))
    p = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 1e-4)])
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    settings = preset("FINAL", threads=1, hemisphere_theta=6, hemisphere_phi=12,
                      deviations=Deviations(thin_coverage=thin, gap_fill=False, hole_rounds=1))
    sources, _ = gather_sources(density, lighting, cache, PARAMS, settings)
    with Executor(1) as executor:
        before = CacheLookup(cache, PARAMS.a, True, caster=caster, layers=True).irradiance(p, n)[1]
        filled = fill_holes(scene, caster, density, sources, cache, SimpleNamespace(p=p, n_shading=n), PARAMS,
                            settings, executor, Progress())
    return filled, p, n, before, caster


def test_thinly_covered_samples_get_records_and_equation_3_over_all_of_them():
    filled, p, n, before, caster = _fill(thin=True)
    thin = np.flatnonzero((before > 0) & (before < THIN_COVERAGE / PARAMS.a))
    assert len(thin) > 0.05 * len(p), len(thin)  # pass 2's records leave many samples thinly covered here
    # Each got new records that accept it (a record is placed on a thin sample or near one).
    assert (filled.w[thin] > before[thin] + 1e-9).mean() > 0.95
    # At the thin samples and the holes E is Equation 3 over the whole cache, old records and new (a
    # sample covered well keeps its records: the hole records' small zones are left to fine-zones).
    E_all, w_all = CacheLookup(filled.cache, PARAMS.a, True, caster=caster, layers=True).irradiance(p, n)
    covered = np.flatnonzero((before < THIN_COVERAGE / PARAMS.a) & (filled.w > 0))
    assert np.allclose(filled.w[covered], w_all[covered], rtol=1e-9)
    assert np.allclose(filled.E[covered], E_all[covered], rtol=1e-9, atol=1e-12)
    assert np.isfinite(filled.E).all()


def test_without_it_only_samples_no_record_accepts_get_records():
    off, _, _, before, _ = _fill(thin=False)
    on, _, _, _, _ = _fill(thin=True)
    assert off.hole_records < on.hole_records
    thin = (before > 0) & (before < THIN_COVERAGE / PARAMS.a)
    assert np.array_equal(off.w[thin], before[thin])  # untouched: the thin samples keep their records
