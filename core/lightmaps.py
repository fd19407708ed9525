"""Light maps from the texel samples' irradiance: splat, (E_direct + E_indirect) / pi, dilate."""
from __future__ import annotations

import numpy as np

from . import texels as texel_stage
from .dilate import dilate


def write_lightmaps(scene, targets, padding: int, progress, stats, fill_buried: bool = True) -> dict:
    """Per target name: RGBA light map, centre-inside and buried masks, direct and indirect E / pi images.

    targets : the pipeline's per-target work (points, raster, E_direct, E_indirect), in
    ``scene.targets`` order. fill_buried : buried texels (:func:`buried_texels`) take their
    neighbours' light by dilation (deviation: buried-texels). Returns the
    :class:`~core.pipeline.BakeResult` fields ``lightmaps``, ``centre_inside``, ``buried``, ``direct``,
    ``indirect`` and ``coverage``.
    """
    progress.begin("Writing light maps")
    out = {"lightmaps": {}, "centre_inside": {}, "buried": {}, "direct": {}, "indirect": {}, "coverage": {}}
    with stats.stage("dilate"):
        for target, t in zip(scene.targets, targets):
            direct_img = texel_stage.splat(t.E_direct, t.points, t.raster) / np.pi
            indirect_img = texel_stage.splat(t.E_indirect, t.points, t.raster, weight=t.indirect_weight) / np.pi
            buried = buried_texels(t)
            baked = t.raster.coverage & ~buried if fill_buried else t.raster.coverage
            rgb, coverage = dilate((direct_img + indirect_img).astype(np.float32), baked, padding + 2)
            rgba = np.concatenate([rgb, coverage[..., None].astype(np.float32)], axis=2)
            out["lightmaps"][target.name] = finite(rgba, target.name)
            out["centre_inside"][target.name] = t.raster.centre_inside
            out["buried"][target.name] = buried
            out["coverage"][target.name] = t.raster.coverage
            out["direct"][target.name] = direct_img.astype(np.float32)
            out["indirect"][target.name] = indirect_img.astype(np.float32)
    stats.add(texels_buried=int(sum(b.sum() for b in out["buried"].values())))
    return out


def buried_texels(t) -> np.ndarray:
    """(H, W) bool covered texels whose whole footprint lies inside closed geometry: a floor's texels
    under a wall standing on it (texel validity gave every sample, and every footprint point of a
    straddling texel, no share of the indirect light: :func:`core.validity.indirect_weights`).

    No camera sees them, but a bilinear filter reads them for the visible floor's last half texel
    at the wall's foot: Cycles bakes them black, which draws a dark line along every wall in a
    game engine. All False when the indirect light was not baked (texel validity did not run).
    """
    raster = t.raster
    if t.indirect_weight is None:
        return np.zeros((raster.height, raster.width), bool)
    share = texel_stage.splat(np.ones((len(t.points), 1)), t.points, raster, weight=t.indirect_weight)[..., 0]
    return raster.coverage & (share <= 0.0)


def finite(image: np.ndarray, name: str) -> np.ndarray:
    """Light maps never carry NaN or inf silently: fail loudly naming the target."""
    if not np.isfinite(image).all():
        bad = int((~np.isfinite(image)).sum())
        raise FloatingPointError(f"{name}: {bad} non-finite light-map values (please report this scene)")
    return image.astype(np.float32)
