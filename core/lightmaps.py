"""Light maps from the texel samples' irradiance: splat, (E_direct + E_indirect) / pi, dilate."""
from __future__ import annotations

import numpy as np

from . import texels as texel_stage
from .dilate import dilate


def write_lightmaps(scene, targets, padding: int, progress, stats) -> dict:
    """Per target name: RGBA light map, centre-inside mask, direct and indirect E / pi images.

    targets : the pipeline's per-target work (points, raster, E_direct, E_indirect), in
    ``scene.targets`` order. Returns the :class:`~core.pipeline.BakeResult` fields ``lightmaps``,
    ``centre_inside``, ``direct``, ``indirect`` and ``coverage``.
    """
    progress.begin("Writing light maps")
    out = {"lightmaps": {}, "centre_inside": {}, "direct": {}, "indirect": {}, "coverage": {}}
    with stats.stage("dilate"):
        for target, t in zip(scene.targets, targets):
            direct_img = texel_stage.splat(t.E_direct, t.points, t.raster) / np.pi
            indirect_img = texel_stage.splat(t.E_indirect, t.points, t.raster, weight=t.indirect_weight) / np.pi
            rgb, coverage = dilate((direct_img + indirect_img).astype(np.float32), t.raster.coverage, padding + 2)
            rgba = np.concatenate([rgb, coverage[..., None].astype(np.float32)], axis=2)
            out["lightmaps"][target.name] = finite(rgba, target.name)
            out["centre_inside"][target.name] = t.raster.centre_inside
            out["coverage"][target.name] = t.raster.coverage
            out["direct"][target.name] = direct_img.astype(np.float32)
            out["indirect"][target.name] = indirect_img.astype(np.float32)
    return out


def finite(image: np.ndarray, name: str) -> np.ndarray:
    """Light maps never carry NaN or inf silently: fail loudly naming the target."""
    if not np.isfinite(image).all():
        bad = int((~np.isfinite(image)).sum())
        raise FloatingPointError(f"{name}: {bad} non-finite light-map values (please report this scene)")
    return image.astype(np.float32)
