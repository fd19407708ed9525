"""The uniform world's light through the records (deviation: sky-gathering, docs/DEVIATIONS.md).

A uniform sky is light as smooth as the indirect light the records exist for. At Final, pass 3's
gathering rays that escape already read it (:func:`core.real_rays.trace_real`, the sky channels of
:class:`core.gather_cells.CellSums`); Preview's records have no gathering, so they cast
PREVIEW_SKY_RAYS rays of their own, one per cell of a small hemisphere, that only ask whether they
escape (:func:`gather_sky`). Either way each record carries ``E_sky`` with its own gradients, and
Equation 3 interpolates it at the texels into the direct-light image.
"""
from __future__ import annotations

import numpy as np

from .constants import CELL_DISTANCE_FLOOR, PREVIEW_SKY_ROWS, PREVIEW_SKY_COLUMNS, STREAM_SKY
from .executor import slices
from .gather_cells import CellSums, limit_gradients
from .hemisphere import Hemisphere, local_frames
from .real_rays import through_glass, trace_real

SKY_BATCH = 1024
"""Records whose sky rays are cast together (~130k rays)."""


def gathered_sky(scene, settings) -> np.ndarray | None:
    """The world's radiance (3,) when the records gather the sky for the direct-light image, else None.

    Only when the bake writes both direct and indirect light (the records exist and the texels take
    both) and, at Final, with standard gathering (virtual rays carry no sky). A gathering ray that meets
    glass brings the sky beyond it as a shadow ray would (:func:`core.real_rays.through_glass`).
    """
    world = scene.world
    if not (settings.deviations.sky_gathering and settings.direct and settings.indirect and settings.photons > 0
            and not (settings.refine and settings.reuse_photon_paths) and not world.is_black):
        return None
    return np.asarray(world.radiance, np.float64).reshape(3)


def gather_sky(caster, cache, sky: np.ndarray, a: float, R_min: float, gradient_limiting: bool, seed: int,
               stream, executor, progress=None) -> tuple[object, int]:
    """``cache`` with E_sky and its gradients from PREVIEW_SKY_ROWS x PREVIEW_SKY_COLUMNS rays per record
    that only ask whether they escape (Preview: its records gather nothing else), and the rays cast.

    sky : the world's radiance (3,); stream : ids after ``seed`` of each batch's generator
    ``[seed, *stream, batch]``.
    """
    H = Hemisphere(PREVIEW_SKY_ROWS, PREVIEW_SKY_COLUMNS)
    serial = caster.serial()
    r_floor = CELL_DISTANCE_FLOOR * a * R_min
    prefix = [seed, *np.atleast_1d(stream).tolist()]

    def run(index, s):
        rng = np.random.default_rng([*prefix, index])
        p_k, n_k = cache.p[s], cache.n[s]
        t1, t2, n = local_frames(n_k)
        sums = CellSums(len(p_k), H, sky=True)
        found, _, _ = trace_real(serial, (p_k, t1, t2, n), np.arange(len(p_k) * H.cells), sums, rng, sky)
        through_glass(serial, found, sums, sky)
        E, grad_r, grad_t, _ = sums.irradiance_and_gradients(t1, t2, n, r_floor)
        return E[:, 3:], grad_r[:, 3:], grad_t[:, 3:], len(p_k) * H.cells + sums.glass_rays

    parts = executor.map_chunks(run, slices(len(cache), SKY_BATCH), progress)
    out = cache.take(slice(None))
    if not parts:
        out.E_sky, out.grad_r_sky, out.grad_t_sky = np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3, 3))
        return out, 0
    E, grad_r, grad_t = (np.concatenate([part[i] for part in parts]) for i in range(3))
    if gradient_limiting:  # deviation: gradient-limiting, docs/DEVIATIONS.md
        grad_t, grad_r = limit_gradients(E, grad_t, grad_r, a * cache.R)
    out.E_sky, out.grad_r_sky, out.grad_t_sky = E, grad_r, grad_t
    rays = sum(part[3] for part in parts)
    caster.rays_cast += rays
    return out, rays
