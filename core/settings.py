"""Bake settings: one frozen, typed dataclass that crosses the bpy border once.

Every field states its meaning, unit and typical value (the README's settings
table is generated from the same words). Quality presets are named bundles of
these fields; :func:`preset` returns them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from .constants import DIRECT_FOOTPRINT_SIDE, HOLE_ROUNDS

QUALITIES = ("PREVIEW", "FINAL", "CUSTOM")


@dataclass(frozen=True)
class Deviations:
    """Switches for the mechanisms beyond the paper (docs/DEVIATIONS.md describes each and what it
    measured). The defaults are today's bake; turning one off runs the paper's step instead."""

    texel_validity: bool = True
    """Texel samples inside closed geometry get no indirect light and no hole record."""
    record_validity: bool = True
    """Final: a hole record whose real gathering rays mostly hit back faces is inside geometry: E_k = 0."""
    photon_evidence: bool = True
    """A sample or hole record the back-face votes put inside geometry is outside after all when a photon
    arrived within half of R_min on a like-facing surface that sees its side (walls whose normals point
    the wrong way); and the votes do not count the backs of faces lit mostly from behind."""
    wall_sectors: bool = True
    """Records find the walls in their tangent plane; light is not interpolated past them."""
    zone_photon_floor: bool = True
    """Preview: a record's zone holds at least ZONE_PHOTONS photons (R_k floored), however small R_min."""
    surface_coverage: bool = True
    """Pass 2: E_k's kernel is normalised over the surface inside its disc (probe rays); Preview, and Final
    with standard gathering (not with photon-path reuse, whose virtual rays are biased the other way)."""
    leave_one_out: bool = True
    """A record placed at a photon leaves that photon out of its own E_k (the photon it sits on is
    certain, not a sample of the density around it)."""
    neighbour_clamp: bool = True
    """R_k <= R_j + |p_k - p_j| between records ([KBPZ06])."""
    clamp_recovery: bool = True
    """Pass 2 (with neighbour_clamp): photons the final clamp leaves outside every zone start records
    again, Algorithm 1 over them, so every photon stays covered as the paper's loop leaves it."""
    probe_rays: bool = True
    """Pass 3: a few real rays per record first; they bound which photons lend virtual rays."""
    virtual_thinning: bool = True
    """Pass 3: at most VIRTUAL_PER_CELL virtual rays per cell of a record, kept at random."""
    zone_visibility: bool = True
    """Pass 3: photons of a zone sector the record cannot see lend no virtual ray."""
    path_visibility: bool = False
    """Pass 3: a virtual ray counts only if its record sees the photon's previous hit (one occlusion ray
    each; off by default: reuse then casts more rays than standard gathering, docs/DEVIATIONS.md)."""
    virtual_cell_minimum: bool = False
    """Pass 3: a cell fewer than VIRTUAL_MIN_PER_CELL virtual rays reached casts a real ray instead (off by
    default: it exposes pass 2's dark hit shading on Sponza, docs/DEVIATIONS.md)."""
    gathered_radius: bool = True
    """Pass 3: R_k becomes the harmonic mean of the record's gathering-ray distances (clamped by its
    neighbours, walls found again); off, R_k stays Figure 3's photon estimate from pass 2."""
    adaptive_gathering: bool = True
    """Pass 3: a record whose E_k's standard error (from its cells) exceeds GATHER_ERROR gathers again,
    up to GATHER_ROUNDS times, and averages (docs/DEVIATIONS.md)."""
    harmonic_cell_radiance: bool = True
    """Pass 3: a cell's virtual rays are averaged as the flux-weighted harmonic mean."""
    hit_grid: bool = True
    """Pass 3: a gathering hit that sees its cell's centroid reads E_direct + E_indirect from a grid of
    cells on its triangle, computed once per cell, instead of a record lookup and shadow rays of its own."""
    open_cells: bool = True
    """Pass 3 (with hit_grid): a hit in a grid cell whose centroid sees the cell's three corners reads the
    cell without an occlusion ray of its own (a wall that cuts the cell cuts one of those three lines)."""
    gap_gathering: bool = True
    """Pass 3 (with hit_grid): a hit near its record whose surface faces the record's gathers its indirect
    light by a walk of its own (bouncing while it stays in the gap) instead of the records around it."""
    corner_gathering: bool = True
    """Pass 3 (with gap_gathering): a hit within a R_min of its record and near the record's tangent plane
    (the foot of a wall rising from the record's surface) gathers by the gap walk too, facing the record
    or not."""
    light_selection: bool = True
    """Pass 3, in scenes of SELECTION_LAMPS point, spot and area lights or more: a gathering hit shaded on its own
    casts one shadow ray among them, toward a lamp drawn by its unoccluded light there, instead of one per lamp
    (core/light_selection.py)."""
    light_budget: bool = True
    """In scenes of BUDGET_LAMPS soft lamps or more (area lights, point and spot lights with a radius): a point's
    soft shadow rays are shared among them by their unoccluded light there, a lamp getting BUDGET_SCALE x
    ``direct_samples`` x its share (at least 1, at most ``direct_samples``), and a footprint point's lamps under
    DRAWN_SHARE share one drawn ray, instead of rays to every lamp (core/light_budget.py)."""
    nearest_photon_fallback: bool = True
    """Pass 3: a gathering hit no record accepts takes the nearest visible photon's irradiance."""
    fallback_empty_disc: bool = True
    """Pass 3 (with nearest_photon_fallback): the lent irradiance is at most FALLBACK_EMPTY_DISC photons'
    power over the disc the lending photon's distance spans: an empty disc that wide says the hit is dark."""
    gradient_limiting: bool = True
    """Pass 3: |grad_t| <= GRADIENT_LIMIT E_k / (a R_k) (0.3 x E_k across the zone) and |grad_r| <= E_k."""
    fine_zones: bool = True
    """Texels inside narrow zones are interpolated per sample, not once at their centroid; Final only."""
    hole_rounds: int = HOLE_ROUNDS
    """Rounds of hole records (section 3.4); the paper places them once."""
    gap_fill: bool = True
    """Texel samples no record accepts take Equation 3 over zones widened by GAP_TEXELS texels (walls and
    visibility checked past a zone) before any hole record is placed; where hole records are estimated
    from photons only (Preview, photon-path reuse): Final's standard gathering gathers one instead."""
    thin_coverage: bool = True
    """Texel samples whose accepted records' weights sum below THIN_COVERAGE / a get hole records too (first
    round), as samples no record accepts do; Final with standard gathering only."""
    nearest_record_fallback: bool = True
    """Texel samples still uncovered after the hole rounds take the nearest record's E_k."""
    record_visibility: bool = True
    """A record (or a hole record's photon) off a texel sample's tangent plane counts only if it
    sees the sample: no light from a closed box's inside onto the floor under it."""
    direct_footprint: bool = True
    """Texels a shadow edge crosses take direct light over DIRECT_FOOTPRINT_PER_AXIS^2 jittered points of
    their footprint, as Cycles' bake integrates it (core/direct_footprint.py)."""
    buried_texels: bool = True
    """Texels partly or wholly inside closed geometry (a floor's texels a wall standing on it cuts or covers)
    take their whole neighbours' light in the light map (dilation), so a bilinear filter draws no dark line
    at the wall's foot. Off: Cycles' texel means, the part under the wall at 0 (core/lightmaps.py
    ``outside_shares``; ``BakeResult.as_cycles`` either way)."""
    transparent_shadows: bool = True
    """Shadow rays and photons pass transmissive triangles (Geometry.transmission), as Cycles'
    transparent shadows; off, every triangle is opaque."""
    contact_faces: bool = True
    """Texel samples on a face another face touches face to face (a building's bottom on a ground plane, a
    cabinet's back flush against a one-face wall) get no light, as in Cycles: their rays would start past
    the touching face (core/contact.py). Off: they are lit from beyond it."""
    under_sheets: bool = True
    """Texel samples under a face lying over theirs nearer than the rays' offset (a decal 80 um over its wall)
    get no light, as in Cycles (core/contact.py ``under_sheet``). Off: they are lit from beyond the sheet."""
    crease_folding: bool = True
    """A texel with a sample on another triangle than the one under its centre (across a crease, or an edge
    between coplanar triangles) is sampled on that triangle alone, over the square Cycles jitters its bake
    samples in, as Cycles bakes it (core/crease_folding.py, core/raster.py:centre_footprints)."""
    edge_folding: bool = True
    """So is a texel whose centre lies on a triangle but misses a sub-sample (past the chart's edge), instead of
    being left to its samples on the chart (core/raster.py:rasterize). The add-on turns it off from Blender 5.2,
    whose bake jitters over the whole texel."""
    crevice_records: bool = True
    """Final: a texel sample whose surroundings stand nearer than a zone (tracery 2 cm before its wall, the
    crease under an overhang, a corner) gathers a record of its own and takes its E_k instead of Equation 3's
    (core/crevice_records.py)."""
    portal_photons: bool = True
    """A share of a sun's and the world's photons take lines through the scene's light portals (Cycles area
    lights with Portal on, in a window) instead of the disc around the scene, weighted so the light is the
    same in expectation (core/portals.py). Off: portals are ignored, as they always emit nothing."""
    sky_gathering: bool = True
    """The world's light reaches the texels through the records (Final: their gathering rays that escape
    read it; Preview: rays of their own; Equation 3 interpolates it with its own gradients) instead of
    shadow rays per texel sample; it stays in the direct-light image; a ray that meets glass brings the
    sky beyond it as a shadow ray would. Not with photon-path reuse (virtual rays carry no sky)."""


@dataclass(frozen=True)
class BakeSettings:
    # -- what to compute ---------------------------------------------------
    quality: str = "FINAL"
    """PREVIEW = passes 1-2 (photon map + coarse cache); FINAL = passes 1-3 (refined cache)."""
    direct: bool = True
    """Bake direct light (shadow rays from every texel sample to every light)."""
    indirect: bool = True
    """Bake indirect light from the photon-driven irradiance cache."""

    # -- pass 1: photon map ------------------------------------------------
    photons: int = 1_000_000
    """Photons emitted (the budget), shared among lights by power. Typical 250k (Preview) - 4M."""
    max_bounces: int = 64
    """Safety limit on diffuse bounces: photons stop by Russian roulette on the albedo, so light
    converges (the paper caps at 4-9; a cap of 6 leaves a closed albedo-0.8 box 26 % dark)."""

    density_control: int = 0
    """Section 3.4 density control: n, the most photons wanted in a record's zone of influence
    (Equation 4); discarded photons' power goes to their neighbours. 0 = off (the paper's results).
    Typical 32-64 for scenes whose photon map outgrows memory."""

    # -- pass 2: irradiance cache -----------------------------------------
    a: float = 0.4
    """Ward's accuracy a: records interpolate where w_k > 1/a; zone of influence radius a*R_k. Typical 0.2-0.5."""
    r_nearest: int = 16
    """Photons whose last-hit distances give R_k (harmonic mean, Figure 3)."""
    r_min_texels: float = 2.0
    """R_min as a multiple of the largest texel's world size."""
    r_max_fraction: float = 0.1
    """R_max as a fraction of the scene diagonal."""

    # -- pass 3: refinement -------------------------------------------------
    hemisphere_theta: int = 16
    """Stratified hemisphere: theta rows (cosine-weighted, equal-weight cells)."""
    hemisphere_phi: int = 32
    """Stratified hemisphere: phi columns. theta x phi = 512 cells by default."""
    reuse_photon_paths: bool = False
    """Fill cells with virtual rays from photon paths (the paper, Figure 4); False = standard final
    gathering, a real ray per cell, with the surface-coverage kernel at the hits' records. Off by
    default: virtual rays are +4 % bright (Sponza), which only the plain kernel's darkness hid;
    standard gathering with the coverage kernel is closer on every bench scene at about the same
    cost (docs/DEVIATIONS.md, standard-gathering)."""
    gradients: bool = True
    """Interpolate with rotational and translational irradiance gradients."""

    # -- light maps -------------------------------------------------------
    default_resolution: int = 256
    """Light-map width and height for an object without an override (when texel_density is 0)."""
    texel_density: float = 0.0
    """Texels per scene unit; 0 uses default_resolution. A map grows until its charts fit at this density
    (up to max_resolution). Typical 8-64 for metre-scale scenes."""
    min_resolution: int = 16
    max_resolution: int = 4096
    padding: int = 2
    """Texels of gutter between charts (xatlas padding); dilation fills it."""
    texel_samples: int = 2
    """Sub-samples per texel axis (2 = 2x2 points per texel) for rasterisation."""
    direct_samples: int = 16
    """Shadow-ray samples per texel sample point for soft lights (area, sun angle, soft radius, world)."""
    direct_footprint_side: float = DIRECT_FOOTPRINT_SIDE
    """Width (texels) of the centred square a shadow-edge texel's direct light is averaged over
    (deviation direct-footprint): 0.5 matches Cycles' bake in Blender 5.0-5.1, 1.0 in 5.2 (the
    add-on sets it from the running Blender)."""

    # -- run ----------------------------------------------------------------
    seed: int = 0
    """Seed of every random stream; the same seed gives the same light maps."""
    threads: int = 0
    """Worker threads; 0 = all cores."""
    deviations: Deviations = field(default_factory=Deviations)
    """Mechanisms beyond the paper, each switchable (docs/DEVIATIONS.md); defaults = all on."""

    def __post_init__(self):
        if self.quality not in QUALITIES:
            raise ValueError(f"quality must be one of {QUALITIES}, got {self.quality!r}")
        checks = {
            "photons": self.photons >= 0,
            "density_control": self.density_control >= 0,
            "max_bounces": 1 <= self.max_bounces <= 255,  # core/photons.py counts bounces in a uint8
            "a": 0.0 < self.a <= 2.0,
            "r_nearest": self.r_nearest >= 1,
            "hemisphere_theta": self.hemisphere_theta >= 1,
            "hemisphere_phi": self.hemisphere_phi >= 1,
            "default_resolution": 1 <= self.default_resolution <= 16384,
            "texel_density": self.texel_density >= 0,
            "padding": self.padding >= 0,
            "texel_samples": 1 <= self.texel_samples <= 8,
            "direct_samples": self.direct_samples >= 1,
            "direct_footprint_side": 0.0 < self.direct_footprint_side <= 1.0,
            "threads": self.threads >= 0,
            "deviations.hole_rounds": self.deviations.hole_rounds >= 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValueError("invalid bake settings: " + ", ".join(f"{k}={_field(self, k)!r}" for k in bad))

    @property
    def refine(self) -> bool:
        """Run pass 3 (refinement)?"""
        return self.quality != "PREVIEW"


def _field(settings, dotted: str):
    for part in dotted.split("."):
        settings = getattr(settings, part)
    return settings


def preset(quality: str, **overrides) -> BakeSettings:
    """Settings of a named quality preset, with explicit overrides applied."""
    base = {
        "PREVIEW": BakeSettings(quality="PREVIEW", photons=250_000, direct_samples=8),
        "FINAL": BakeSettings(quality="FINAL"),
        "CUSTOM": BakeSettings(quality="CUSTOM"),
    }[quality.upper()]
    return replace(base, **overrides)
