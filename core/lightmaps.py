"""Light maps from the texel samples' irradiance: splat, (E_direct + E_indirect) / pi, dilate."""
from __future__ import annotations

import numpy as np

from . import texels as texel_stage
from .constants import SHARE_TOLERANCE
from .dilate import dilated_rgba


def write_lightmaps(scene, targets, padding: int, progress, stats, visible: bool = True) -> dict:
    """Per target name: RGBA light map, centre-inside and buried masks, direct and indirect E / pi images.

    targets : the pipeline's per-target work (points, raster, E_direct, E_indirect), in
    ``scene.targets`` order. visible : buried texels (:func:`outside_shares`) take their neighbours'
    light (deviation: buried-texels); False: the light map holds Cycles' texel means. Returns the
    :class:`~core.pipeline.BakeResult` fields ``lightmaps``, ``centre_inside``, ``buried``,
    ``direct``, ``indirect`` and ``coverage``.
    """
    progress.begin("Writing light maps")
    out = {"lightmaps": {}, "centre_inside": {}, "buried": {}, "direct": {}, "indirect": {}, "coverage": {}}
    with stats.stage("dilate"):
        for target, t in zip(scene.targets, targets):
            direct_img = texel_stage.splat(t.E_direct, t.points, t.raster) / np.pi
            indirect_img = texel_stage.splat(t.E_indirect, t.points, t.raster, weight=t.indirect_weight) / np.pi
            buried = t.raster.coverage & (outside_shares(t) < 1.0 - SHARE_TOLERANCE)
            baked = t.raster.coverage & ~buried if visible else t.raster.coverage
            rgba = dilated_rgba((direct_img + indirect_img).astype(np.float32), baked, padding + 2)
            out["lightmaps"][target.name] = finite(rgba, target.name)
            out["centre_inside"][target.name] = t.raster.centre_inside
            out["buried"][target.name] = buried
            out["coverage"][target.name] = t.raster.coverage
            out["direct"][target.name] = direct_img.astype(np.float32)
            out["indirect"][target.name] = indirect_img.astype(np.float32)
    stats.add(texels_buried=int(sum(b.sum() for b in out["buried"].values())))
    return out


def outside_shares(t) -> np.ndarray:
    """(H, W) float64 the share of each texel's footprint outside closed geometry: 1 on open surface, 0
    under a wall standing on it, in between at its foot (texel validity's votes over the samples and
    straddling texels' footprints, :func:`core.validity.indirect_weights`); 1 everywhere when the
    indirect light was not baked (texel validity did not run). A covered texel with a share below 1
    is *buried*.

    The bake's direct and indirect images hold what Cycles bakes there: the footprint's mean, its
    inside part at 0. No camera sees that part, but a game engine's bilinear filter spreads the
    texel over the visible floor up to the wall: a dark line along every wall's foot. The light map
    takes a buried texel's light from its whole neighbours instead (the dilation). Not its own
    outside part's mean (its value over the share): the share and the direct light's footprint are
    voted at different points, and on Sponza at 16 texels/m (16 share points, 64 direct ones) the
    quotient put 1.5 % of the texels a wall cuts above 1.2x their brightest whole neighbour (up to 2.2x).
    """
    raster = t.raster
    if t.indirect_weight is None:
        return np.ones((raster.height, raster.width))
    return texel_stage.splat(np.ones((len(t.points), 1)), t.points, raster, weight=t.indirect_weight)[..., 0]


def finite(image: np.ndarray, name: str) -> np.ndarray:
    """Light maps never carry NaN or inf silently: fail loudly naming the target."""
    if not np.isfinite(image).all():
        bad = int((~np.isfinite(image)).sum())
        raise FloatingPointError(f"{name}: {bad} non-finite light-map values (please report this scene)")
    return image.astype(np.float32)
