"""Dilation: grow light-map charts into their gutter so bilinear filtering and
mip-mapping never read the empty texels between charts (lightmapper.h style).

A pure function over image buffers (STYLE principle 12).
"""
from __future__ import annotations

import numpy as np


def dilate(image: np.ndarray, coverage: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Fill uncovered texels from their covered 8-neighbours, one ring per iteration.

    Parameters
    ----------
    image : (H, W, C) float32 texel values (e.g. C = 3 irradiance / pi).
    coverage : (H, W) bool, True where a texel holds a baked value.
    iterations : rings to grow (typical = padding, 2-4); 0 returns copies.

    Returns
    -------
    image : (H, W, C) float32, a new array; covered texels keep their values
        bit for bit, a texel filled in iteration i holds the mean of the texels
        covered after iteration i-1 among its 8 neighbours.
    coverage : (H, W) bool, the covered texels after dilation.
    """
    image = np.asarray(image)
    coverage = np.asarray(coverage, dtype=bool)
    if image.ndim != 3 or image.shape[:2] != coverage.shape:
        raise ValueError(f"dilate: image {image.shape} must be (H, W, C) with coverage (H, W), got coverage {coverage.shape}")
    if iterations < 0:
        raise ValueError(f"dilate: iterations must be >= 0, got {iterations}")
    out = image.astype(np.float32, copy=True)
    covered = coverage.copy()
    h, w, c = out.shape
    for _ in range(int(iterations)):  # each ring depends on the previous one
        if covered.all() or not covered.any():
            break
        padded_value = np.zeros((h + 2, w + 2, c), np.float64)
        padded_value[1:-1, 1:-1] = np.where(covered[:, :, None], out, 0.0)
        padded_count = np.zeros((h + 2, w + 2), np.float64)
        padded_count[1:-1, 1:-1] = covered
        total = np.zeros((h, w, c), np.float64)
        count = np.zeros((h, w), np.float64)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx == 0 and dy == 0:
                    continue
                total += padded_value[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx]
                count += padded_count[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx]
        fill = ~covered & (count > 0)
        out[fill] = (total[fill] / count[fill][:, None]).astype(np.float32)
        covered = covered | fill
    return out, covered


def dilated_rgba(image: np.ndarray, coverage: np.ndarray, iterations: int) -> np.ndarray:
    """(H, W, C + 1) float32: :func:`dilate`'s image with an alpha channel, 1 where a texel is covered
    or was filled, 0 elsewhere (light maps and atlases are written this way)."""
    filled, covered = dilate(image, coverage, iterations)
    return np.concatenate([filled, covered[..., None].astype(np.float32)], axis=2)
