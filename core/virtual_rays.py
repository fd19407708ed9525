"""Virtual rays of pass 3 (Figure 4a-b): photon paths reused as gathering rays.

Each indirect photon of record k's zone yields a *virtual ray* from p_k toward the photon's
previous hit p_lh; kept if p_lh lies above k's tangent plane, it fills the cell it passes
through with the radiance leaving the linked previous photon, albedo x (E_direct + E_indirect) / pi.
"""
from __future__ import annotations

import numpy as np

from .constants import ABOVE_PLANE, RADIANCE_FLOOR, VIRTUAL_MIN_PER_CELL, VIRTUAL_PER_CELL
from .gather_cells import CellSums
from .hemisphere import to_local
from .zone_visibility import zone_visibility
from .vectors import norms


def fill_virtual(caster, sources, frames, zone_lengths: np.ndarray, zone_photons: np.ndarray,
                 zone_radius: np.ndarray, sums: CellSums, rng: np.random.Generator) -> tuple[int, int, int, int]:
    """Add the virtual rays of each record's zone photons to the cells no real ray measured yet.

    frames : (p_k, t1, t2, n) of the batch's B records. zone_lengths (B,), zone_photons (sum,):
    the photons of each zone (pass 2). zone_radius (B,): only photons nearer than this lend rays
    (inf: the whole zone; see :mod:`core.refinement`'s probe rays).
    Returns (virtual rays added, cells they filled, zone-visibility rays cast, path-visibility rays cast).
    """
    p_k, t1, t2, n = frames
    B, C = sums.B, sums.H.cells
    density = sources.density
    rec, ph, prev, offset, offset_length = _zone_photons_with_paths(density, p_k, zone_lengths, zone_photons,
                                                                   zone_radius)
    if sources.deviations.virtual_thinning:  # deviation: virtual-thinning, docs/DEVIATIONS.md
        # A zone holds far more photons than a record has cells (9 per filled cell on the occluded
        # building): beyond VIRTUAL_PER_CELL x cells a record's photons are thinned at random,
        # which keeps every direction's share and saves the bookkeeping of the rest.
        per_record = np.bincount(rec, minlength=B)
        keep_p = np.minimum(1.0, VIRTUAL_PER_CELL * C / np.maximum(per_record, 1))
        kept = rng.random(len(rec)) < keep_p[rec]
        rec, ph, prev, offset, offset_length = rec[kept], ph[kept], prev[kept], offset[kept], offset_length[kept]
    visibility_rays = path_rays = 0
    if sources.deviations.zone_visibility:  # deviation: zone-visibility, docs/DEVIATIONS.md
        visible, visibility_rays = zone_visibility(caster, density.p, density.n, p_k, n, t1, t2, rec, ph, B,
                                                   offset, offset_length)
        rec, ph, prev = rec[visible], ph[visible], prev[visible]
    # Figure 4b: the ray from p_k toward the photon's previous hit, in the record's frame.
    v = density.last_hit[ph] - p_k[rec]
    local = to_local(v, t1[rec], t2[rec], n[rec])
    dist = norms(local)
    above = local[:, 2] > ABOVE_PLANE * np.maximum(dist, 1e-300)
    rec, ph, prev, local, dist = rec[above], ph[above], prev[above], local[above], dist[above]
    if sources.deviations.path_visibility:  # deviation: path-visibility, docs/DEVIATIONS.md
        # The photon saw its previous hit, the record may not: beside a block on the floor a photon
        # a few centimetres out came from the ceiling behind the block, and its ray would fill a
        # cell facing the block's dark side with the ceiling's light (Cornell floor's 8x8-block
        # error 9.8 -> 7.7 %).
        seen = caster.visible_between(p_k[rec], n[rec], density.last_hit[ph], density.n[prev])
        rec, ph, prev, local, dist = rec[seen], ph[seen], prev[seen], local[seen], dist[seen]
        path_rays = len(seen)
    w_local = local / dist[:, None]
    cell = rec * C + sums.H.cell_of(w_local)
    L_virtual = sources.radiance_out[prev]
    inv = None
    if sources.deviations.harmonic_cell_radiance:  # deviation: harmonic-cell-radiance, docs/DEVIATIONS.md
        # Photons reach the zone with a density proportional to the radiance of the direction they
        # come from, so a plain mean of their radiances over-weights the bright part of a cell
        # (+47 % on the Cornell floor under the ceiling hot spot). The unbiased cell radiance for
        # flux-proportional samples is the flux-weighted harmonic mean sum(phi) / sum(phi / L),
        # accumulated as an equivalent per-ray weight.
        phi = density.photons.power[ph].astype(np.float64).mean(axis=1)
        inv = phi / np.maximum(L_virtual.mean(axis=1), RADIANCE_FLOOR)  # each ray's share of sum(phi / L)
    sel = ~(sums.count[cell] > 0)  # a probe's real ray already measured this cell
    if sources.deviations.virtual_cell_minimum:  # deviation: virtual-cell-minimum, docs/DEVIATIONS.md
        # Over one photon the harmonic mean is that photon's radiance, and photons come more often
        # from a cell's brighter directions: a lone photon over-estimates its cell. Such cells cast
        # a real ray instead (Figure 4c).
        per_cell = np.bincount(cell[sel], minlength=B * C)
        sel &= per_cell[cell] >= VIRTUAL_MIN_PER_CELL
    sums.add_rays(cell[sel], L_virtual[sel], w_local[sel], dist[sel], None if inv is None else inv[sel])
    rec, dist = rec[sel], dist[sel]
    sums.add_distances(np.bincount(rec, weights=1.0 / dist, minlength=B), np.bincount(rec, minlength=B))
    cells_virtual = int(np.count_nonzero(np.bincount(cell[sel], minlength=B * C)))
    return len(rec), cells_virtual, visibility_rays, path_rays


def _zone_photons_with_paths(density, p_k, zone_lengths, zone_photons, zone_radius):
    """(record, photon, previous photon, offset photon - record (m, 3), its length) for the zone
    photons that have a previous hit (Figure 4a) and lie within ``zone_radius`` of their record."""
    rec = np.repeat(np.arange(len(p_k)), zone_lengths)
    ph = zone_photons
    prev = density.photons.prev[ph]
    keep = prev >= 0
    rec, ph, prev = rec[keep], ph[keep], prev[keep].astype(np.int64)
    offset = density.p[ph] - p_k[rec]
    offset_length = norms(offset)
    near = offset_length < zone_radius[rec]
    return rec[near], ph[near], prev[near], offset[near], offset_length[near]
