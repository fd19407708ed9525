"""Direct light integrated over the footprint of texels a shadow edge crosses (deviation: direct-footprint).

Cycles bakes a texel by jittering its sample over a footprint (a centred square, half a texel wide
in Blender 5.0-5.1, the whole texel from 5.2: ``BakeSettings.direct_footprint_side``), so a texel a
hard shadow edge crosses holds the lit share of that square. ``texel_samples`` (2 x 2)
points alias there: a texel reads 0, 1/4, ..., 1 whatever the edge's position (Cornell 256^2,
direct light alone: 13.0 % per texel against Cycles). Here, after direct light at the regular samples:

1. **Edge texels** (:func:`edge_texels`): a texel whose samples' lit shares (from the edge
   evidence, :func:`core.direct.edge_evidence`: independent of the light they keep) disagree by
   more than ``DIRECT_EDGE_CONTRAST`` (where the samples' hull is narrower than the footprint, also
   one whose mean lit share differs that much from a 4-neighbour's on the same surface, centroids
   within ``DIRECT_NEIGHBOUR_TEXELS`` texel sizes).
2. **Footprint**: ``DIRECT_FOOTPRINT_PER_AXIS``^2 stratified jittered points over each edge texel's
   footprint (the centred square of ``direct_footprint_side`` texels that Cycles bakes),
   on the triangles that cover it (:func:`core.texels.footprint_texel_points`); soft emitters take
   ``direct_samples x texel_samples^2 / points`` rays per point (at least 1), so a texel's soft
   shadow rays stay what the regular samples spent.
3. The texel's direct irradiance becomes the mean over its footprint points, written to every one of
   its regular samples (the splat's weights then give that mean back); the samples' positions, and
   so the indirect light, do not change.

Cost grows with the length of the shadow edges, not the map's area. Switch:
``Deviations.direct_footprint``.
"""
from __future__ import annotations

import numpy as np

from .constants import (DIRECT_EDGE_CONTRAST, DIRECT_EDGE_FLOOR, DIRECT_FOOTPRINT_PER_AXIS,
                        DIRECT_NEIGHBOUR_TEXELS, STREAM_DIRECT_FOOTPRINT)
from .direct import DirectResult, shade_direct
from .light_budget import budgeted_lamps, group_draws
from .texels import TargetRaster, TexelPoints, footprint_texel_points

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 weights: which texels disagree is judged on luminance."""


def edge_texels(direct: DirectResult, points: TexelPoints, raster: TargetRaster, texel_size: float,
                neighbours: bool, contrast: float = DIRECT_EDGE_CONTRAST) -> np.ndarray:
    """Flat indices (k,) int64, ascending, of the texels a shadow edge may cross.

    Judged on each sample's lit share s = L(edge_lit) / L(edge_open) (L the luminance, the edge
    evidence of :func:`core.direct.edge_evidence`): 1 in full light, 0 in umbra, whatever the
    falloff, so smooth light (which the symmetric 2 x 2 samples already integrate to second order)
    costs nothing here. The evidence is not the samples' E: judged on E, a texel would keep its
    samples when their noise came out even and lose them when it did not (a biased choice).

    Parameters
    ----------
    direct : the regular samples' :class:`DirectResult` (``edge_lit`` and ``edge_open``, (n, 3) W/m^2).
    points : that target's samples (``texel``, ``weight``, ``p``).
    raster : its image size and coverage.
    texel_size : world size of one texel (neighbours farther apart than
        ``DIRECT_NEIGHBOUR_TEXELS`` of it lie on different surfaces and are not compared).
    neighbours : compare each texel with its 4-neighbours too. Needed only when the regular
        samples' convex hull does not hold the footprint (1 x 1 samples, or a whole-texel
        footprint): where it does, any straight edge through the footprint already splits the
        texel's own samples (2 x 2 samples and the half-texel footprint on Cornell 256^2: the
        neighbour test would flag 3.7x the texels for 0.1 point of error).
    contrast : lit-share difference that marks an edge (typical 0.05).
    """
    size = raster.width * raster.height
    L_open = np.asarray(direct.edge_open, np.float64) @ LUMINANCE
    floor = DIRECT_EDGE_FLOOR * float(L_open.max(initial=0.0))
    if floor <= 0:  # no direct light with edges on this target
        return np.zeros(0, np.int64)
    lit = np.where(L_open > floor, (np.asarray(direct.edge_lit, np.float64) @ LUMINANCE) / np.maximum(L_open, floor),
                   1.0)
    texel = points.texel
    w = points.weight.astype(np.float64)
    w_sum = np.bincount(texel, weights=w, minlength=size)
    covered = w_sum > 0
    safe = np.where(covered, w_sum, 1.0)
    mean = np.bincount(texel, weights=w * lit, minlength=size) / safe
    hi = np.full(size, -np.inf)
    lo = np.full(size, np.inf)
    np.maximum.at(hi, texel, lit)
    np.minimum.at(lo, texel, lit)
    edge = covered & (hi - lo > contrast)
    if not neighbours:
        return np.flatnonzero(edge)
    centroid = np.stack([np.bincount(texel, weights=w * points.p[:, c], minlength=size) for c in range(3)], 1)
    centroid /= safe[:, None]
    near = (DIRECT_NEIGHBOUR_TEXELS * texel_size) ** 2
    img = np.arange(size).reshape(raster.height, raster.width)
    for a, b in ((img[:, :-1], img[:, 1:]), (img[:-1, :], img[1:, :])):
        a, b = a.ravel(), b.ravel()
        both = covered[a] & covered[b] & (((centroid[a] - centroid[b]) ** 2).sum(1) <= near)
        differ = both & (np.abs(mean[a] - mean[b]) > contrast)
        edge[a[differ]] = True
        edge[b[differ]] = True
    return np.flatnonzero(edge)


def footprint_direct(scene, caster, target_index: int, points: TexelPoints, raster: TargetRaster,
                     texel_size: float, direct: DirectResult, settings, stream: int, executor, progress,
                     contact=None) -> tuple[np.ndarray, dict]:
    """Direct irradiance (n, 3) at one target's samples with edge texels integrated over their footprint.

    Parameters
    ----------
    scene, caster : as :func:`core.direct.shade_direct`.
    target_index : the target's index in ``scene.targets`` (``points`` are its samples).
    points, raster, texel_size : the target's samples, image and world texel size.
    direct : :func:`core.direct.shade_direct` (``whole=True``) at ``points``.
    settings : ``BakeSettings`` (``direct_samples``, ``texel_samples``, ``seed``,
        ``direct_footprint_side``).
    stream : the target's random stream id; jitter and shadow rays draw from
        ``[seed, STREAM_DIRECT_FOOTPRINT, stream, ...]``.
    contact : :class:`core.contact.ContactFaces` (deviations: contact-faces, under-sheets): footprint points
        on a face another touches or under a sheet get no light, as ``direct``'s samples there have none; or None.

    Returns
    -------
    E (n, 3) float64 W/m^2 and counters ``direct_footprint_texels``,
    ``direct_footprint_points``, ``direct_footprint_shadow_rays``.
    """
    E = direct.E
    # the regular samples' hull spans 1 - 1/n texels: a wider footprint can hold an edge they miss
    hull = 1.0 - 1.0 / settings.texel_samples
    texels = edge_texels(direct, points, raster, texel_size, neighbours=settings.direct_footprint_side > hull + 1e-9)
    m = DIRECT_FOOTPRINT_PER_AXIS
    rng = np.random.default_rng([settings.seed, STREAM_DIRECT_FOOTPRINT, stream])
    fp = footprint_texel_points(scene, target_index, texels, m, rng, settings.direct_footprint_side,
                                raster.centre_triangle if settings.deviations.crease_folding else None)
    counters = {"direct_footprint_texels": len(texels), "direct_footprint_points": len(fp),
                "direct_footprint_shadow_rays": 0}
    if len(fp) == 0:
        return E, counters
    soft = max(1, -(-settings.direct_samples * settings.texel_samples ** 2 // (m * m)))
    draws = None
    budget = settings.deviations.light_budget
    if budget and soft == 1 and budgeted_lamps(scene.emitters(), soft, drawn=True)[0]:
        # deviation: light-budget: soft lamps of small shares share one ray, drawn evenly over the texel's points
        draws = group_draws(fp.texel, np.random.default_rng([settings.seed, STREAM_DIRECT_FOOTPRINT, stream, 2]))
    E_fp, rays = shade_direct(scene, caster, fp.p, fp.n_shading, fp.n_geometric, soft, settings.seed,
                              (STREAM_DIRECT_FOOTPRINT, stream, 1), executor, progress, budget=budget, draws=draws)
    counters["direct_footprint_shadow_rays"] = rays["shadow_rays"]
    if contact is not None:
        E_fp[contact.samples(fp.p, fp.triangle)] = 0.0
    size = raster.width * raster.height
    w = fp.weight.astype(np.float64)
    texel_E = np.stack([np.bincount(fp.texel, weights=w * E_fp[:, c], minlength=size) for c in range(3)], 1)
    reached = np.bincount(fp.texel, minlength=size) > 0  # a sliver the jittered points all missed keeps its samples
    out = np.array(E, np.float64, copy=True)
    take = reached[points.texel]
    out[take] = texel_E[points.texel[take]]
    return out, counters
