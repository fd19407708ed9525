"""Pass 3: refine every record by final gathering that reuses photon paths (section 3.3, Figure 4).

For record k, the hemisphere above p_k is split into equal-weight cells
(:mod:`core.hemisphere`). Each indirect photon of k's zone of influence
yields a *virtual ray* from p_k to the photon's previous hit p_lh; kept if
p_lh lies above k's tangent plane, it fills the cell it passes through with
the radiance leaving the linked previous photon, albedo x (E_direct +
E_indirect) / pi. Only cells no virtual ray reached cast a real ray; its
radiance comes from the photon nearest to the hit ([Chr99]). The cell
radiances and hit distances give the refined E_k, the rotational and
translational gradients, and a new R_k (harmonic mean of the distances,
clamped again).

With ``reuse_photon_paths=False`` every cell casts a ray: the standard
stratified final gathering the paper compares against (Table 2).

Records are refined in batches, each a pure function of its slice of the
cache, mapped on the executor.
"""
from __future__ import annotations

import numpy as np

from .albedo import albedo as albedo_at
from .executor import Executor, Progress
from .hemisphere import Hemisphere, gradient_to_world, local_frames, to_local
from .irradiance_cache import CacheParameters, IrradianceCache, PhotonDensity, Zones, neighbour_clamp
from .rays import RayCaster
from .scene import Scene
from .settings import BakeSettings

RECORD_BATCH = 256
"""Records refined per chunk: ~75k cells, a few tenths of a second of work."""
NEAREST_CANDIDATES = 8
"""Photons examined around a real ray's hit to find the nearest one on the side the ray sees."""


def refine_records(scene: Scene, caster: RayCaster, density: PhotonDensity, cache: IrradianceCache, zones: Zones,
                   settings: BakeSettings, params: CacheParameters, executor: Executor,
                   progress: Progress | None = None, stream: int = 4) -> tuple[IrradianceCache, dict]:
    """Refined copy of ``cache`` and counters (rays cast, virtual rays, cells filled by them)."""
    K = len(cache)
    if K == 0:
        return cache, {}
    H = Hemisphere(settings.hemisphere_theta, settings.hemisphere_phi)
    photons = density.photons
    E_total = photons.E_direct.astype(np.float64) + photons.E_indirect()
    radiance_out = photons.albedo.astype(np.float64) * E_total / np.pi  # leaving each photon, W/m^2/sr
    serial = caster.serial()
    batches = [slice(s, min(s + RECORD_BATCH, K)) for s in range(0, K, RECORD_BATCH)]
    done = [0]

    def run(job):
        index, s = job
        rng = np.random.default_rng([settings.seed, stream, index])
        out = _refine_batch(scene, serial, density, radiance_out, E_total, cache.p[s], cache.n[s],
                            zones.start[s.start:s.stop + 1], zones.photon, H, settings.reuse_photon_paths, rng)
        done[0] += 1
        if progress is not None:
            progress.update(done[0] / len(batches))
        return out

    results = executor.map(run, list(enumerate(batches)))
    refined = cache.take(slice(None))
    counters = {"refine_rays_cast": 0, "refine_virtual_rays": 0, "refine_cells_virtual": 0, "refine_cells": 0}
    for s, r in zip(batches, results):
        refined.E[s], refined.grad_r[s], refined.grad_t[s] = r["E"], r["grad_r"], r["grad_t"]
        refined.R[s] = np.clip(r["R"], params.R_min, params.R_max)
        for key in counters:
            counters[key] += r[key]
    refined.refined[:] = True
    refined.R = neighbour_clamp(refined.p, refined.R)
    caster.rays_cast += counters["refine_rays_cast"]
    return refined, counters


def _refine_batch(scene: Scene, caster: RayCaster, density: PhotonDensity, radiance_out: np.ndarray,
                  E_total: np.ndarray, p_k: np.ndarray, n_k: np.ndarray, zone_start: np.ndarray,
                  zone_photon: np.ndarray, H: Hemisphere, reuse: bool, rng: np.random.Generator) -> dict:
    B, C = len(p_k), H.cells
    t1, t2, n = local_frames(n_k)
    L_sum = np.zeros((B * C, 3))
    rot_sum = np.zeros((B * C, 3))
    count = np.zeros(B * C)
    r_min = np.full(B * C, np.inf)
    inv_d_sum = np.zeros(B)
    inv_d_count = np.zeros(B)
    virtual = 0

    # -- virtual rays from the photon paths of each zone (Figure 4a-b)
    if reuse:
        lengths = np.diff(zone_start)
        rec = np.repeat(np.arange(B), lengths)
        ph = zone_photon[zone_start[0]:zone_start[-1]].astype(np.int64)
        prev = density.photons.prev[ph]
        keep = prev >= 0
        rec, ph, prev = rec[keep], ph[keep], prev[keep].astype(np.int64)
        v = density.last_hit[ph] - p_k[rec]
        local = to_local(v, t1[rec], t2[rec], n[rec])
        dist = np.linalg.norm(local, axis=1)
        above = local[:, 2] > 1e-9 * np.maximum(dist, 1e-300)
        rec, prev, local, dist = rec[above], prev[above], local[above], dist[above]
        w_local = local / dist[:, None]
        cell = rec * C + H.cell_of(w_local)
        _accumulate(L_sum, rot_sum, count, r_min, cell, radiance_out[prev], w_local, dist, B * C)
        inv_d_sum += np.bincount(rec, weights=1.0 / dist, minlength=B)
        inv_d_count += np.bincount(rec, minlength=B)
        virtual = len(rec)
    cells_virtual = int((count > 0).sum())

    # -- real rays for the cells no virtual ray reached (Figure 4c)
    empty = np.flatnonzero(count == 0)
    rec = empty // C
    w_local = H.sample_cells(empty % C, rng.random((len(empty), 2)))
    d_world = w_local[:, :1] * t1[rec] + w_local[:, 1:2] * t2[rec] + w_local[:, 2:3] * n[rec]
    hits = caster.intersect(p_k[rec], d_world, normals=n[rec])
    L = np.zeros((len(empty), 3))
    hit = hits.hit
    if hit.any():
        L[hit] = _radiance_at_hits(scene, density, E_total, hits.triangle[hit], hits.barycentric[hit],
                                   p_k[rec[hit]] + d_world[hit] * hits.t[hit, None], d_world[hit])
    dist = hits.t
    _accumulate(L_sum, rot_sum, count, r_min, empty, L, w_local, dist, B * C)
    finite = np.isfinite(dist)
    inv_d_sum += np.bincount(rec[finite], weights=1.0 / np.maximum(dist[finite], 1e-300), minlength=B)
    inv_d_count += np.bincount(rec[finite], minlength=B)

    # -- irradiance, gradients and R_k from the cells
    L_cell = (L_sum / np.maximum(count, 1)[:, None]).reshape(B, C, 3)
    rot_cell = (rot_sum / np.maximum(count, 1)[:, None]).reshape(B, C, 3)
    E, g_r, g_t = H.irradiance_and_gradients(L_cell, r_min.reshape(B, C), rot_cell)
    R = np.divide(inv_d_count, inv_d_sum, out=np.full(B, np.inf), where=inv_d_sum > 0)
    return {
        "E": np.maximum(E, 0.0),
        "grad_r": gradient_to_world(g_r, t1, t2, n),
        "grad_t": gradient_to_world(g_t, t1, t2, n),
        "R": R,
        "refine_rays_cast": len(empty),
        "refine_virtual_rays": virtual,
        "refine_cells_virtual": cells_virtual,
        "refine_cells": B * C,
    }


def _accumulate(L_sum, rot_sum, count, r_min, cell, L, w_local, dist, size):
    """Add rays to their cells: radiance, rotational-gradient axis (z x w)/cos, count, min distance."""
    for c in range(3):
        L_sum[:, c] += np.bincount(cell, weights=L[:, c], minlength=size)
    cos = np.maximum(w_local[:, 2], 1e-6)
    rot_sum[:, 0] += np.bincount(cell, weights=-w_local[:, 1] / cos, minlength=size)
    rot_sum[:, 1] += np.bincount(cell, weights=w_local[:, 0] / cos, minlength=size)
    count += np.bincount(cell, minlength=size)
    np.minimum.at(r_min, cell, dist)


def _radiance_at_hits(scene: Scene, density: PhotonDensity, E_total: np.ndarray, triangle: np.ndarray,
                      barycentric: np.ndarray, q: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Radiance toward the ray: albedo at the hit x the nearest photon's irradiance / pi ([Chr99]).

    The nearest photon is taken among those on the side of the surface the ray arrives from.
    """
    k = min(NEAREST_CANDIDATES, len(density.p))
    _, idx = density.tree.query(q, k=k)
    idx = idx.reshape(len(q), k)
    idx = np.minimum(idx, len(density.p) - 1)
    facing = np.einsum("mkj,mj->mk", density.n[idx], direction) < 0
    first = np.where(facing.any(axis=1), facing.argmax(axis=1), 0)
    nearest = idx[np.arange(len(q)), first]
    rho = albedo_at(scene, triangle, barycentric).astype(np.float64)
    return rho * E_total[nearest] / np.pi
