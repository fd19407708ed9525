"""Direct irradiance at surface points: shadow rays toward every light of the scene.

What a texel receives from each emitter, in Blender's units (DEVELOPERS.md).
Conventions below were measured against Cycles 5.0 bakes (Diffuse, Direct,
no Color: the texel holds E / pi):

========================  =========================================================
point, radius 0           E = P cos_s / (4 pi d^2)
point, radius r > 0       ``soft_falloff`` on (Blender's default): a Lambertian disk
                          of radius r facing the receiver, radiance P / (4 pi^2 r^2);
                          off: a sphere of radius r with the same radiance.
spot                      the point light times smoothstep((cos_a - cos_h) /
                          ((1 - cos_h) blend)), cos_a the cosine between the axis and
                          the direction light -> receiver, cos_h = cos(half_angle);
                          blend 0 is a hard edge. Power is the full sphere's.
sun                       E = S cos_s; with half-angle a > 0 a cone of radiance
                          S / (pi sin^2 a)
area                      one-sided, radiance L = P / (pi A) (normalize on)
emissive triangle         two-sided, radiance = Emission Color x Strength
world (uniform)           E = pi L x (cosine-weighted unoccluded fraction)
========================  =========================================================

Normals: the cosine that weights light is taken with the *shading* normal
(``cos_s``); light arriving from below the *geometric* surface
(``n_g . w <= 0``) is rejected outright, and shadow rays leave the surface
on the geometric side. A point thus never receives light through its own
face, even where a smooth shading normal leans toward the light.

Everything here is a pure function of its chunk of points (it is mapped over
texel chunks on the thread pool); randomness comes only from ``rng``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import native_kernels
from .constants import STREAM_DIRECT_EDGE
from .executor import TEXEL_CHUNK, slices
from .lamp_weights import weight_chunks
from .light_budget import budgeted_lamps, drawn_lamps, sample_counts
from .lights import EMISSIVE_KEY, WORLD_KEY, SceneError, ShadowSamples, spot_attenuation  # noqa: F401 (re-exported)
from .lights import _rgb
from .rays import RayCaster
from .scene import Scene
from .vectors import unit

LIGHT_KINDS = ("point", "spot", "sun", "area", "emissive", "world")


@dataclass
class DirectResult:
    """Direct irradiance of a chunk of n points, with work counters.

    E : (n, 3) float64 front-side irradiance, W/m^2 (texel value is E / pi).
    edge_lit, edge_open : (n, 3) float64 the edge evidence (None unless asked for,
        :func:`edge_evidence`): irradiance of samples independent of E's, and the same with every
        ray unblocked; edge_lit / edge_open is a lit share, 1 or 0 away from shadow edges.
    shadow_rays : rays traced per light kind (keys of :data:`LIGHT_KINDS`).
    skipped : per light name (and :data:`EMISSIVE_KEY`, :data:`WORLD_KEY`): points that
        cast no shadow ray toward it (facing away, outside a spot cone, behind an area
        light, or the light has no power).
    """

    E: np.ndarray
    edge_lit: np.ndarray | None = None
    edge_open: np.ndarray | None = None
    shadow_rays: dict = field(default_factory=lambda: {k: 0 for k in LIGHT_KINDS})
    skipped: dict = field(default_factory=dict)

    @staticmethod
    def concatenate(results: list["DirectResult"]) -> "DirectResult":
        """Join chunk results in order: E stacked, counters summed."""
        def stack(name):
            parts = [getattr(r, name) for r in results]
            if any(part is None for part in parts):  # edge evidence no chunk was asked for
                return None
            return np.concatenate(parts) if parts else np.zeros((0, 3))

        rays = {k: sum(r.shadow_rays.get(k, 0) for r in results) for k in LIGHT_KINDS}
        skipped: dict = {}
        for r in results:
            for k, v in r.skipped.items():
                skipped[k] = skipped.get(k, 0) + v
        return DirectResult(stack("E"), stack("edge_lit"), stack("edge_open"), rays, skipped)


def direct_irradiance(scene: Scene, caster: RayCaster, points: np.ndarray, normals: np.ndarray,
                      geo_normals: np.ndarray, samples: int, rng: np.random.Generator,
                      edge_rng: np.random.Generator | None = None, emitters: tuple | None = None,
                      budget: bool = False, draws: np.ndarray | None = None) -> DirectResult:
    """Irradiance from every light, emissive triangle and the world at ``points``.

    Parameters
    ----------
    scene : lights, emissive materials, world.
    caster : ray caster over ``scene.geometry.positions`` (shadow rays).
    points : (n, 3) float64 scene-local surface points.
    normals : (n, 3) shading normals (weight the cosine); normalised here.
    geo_normals : (n, 3) geometric normals (reject light from below, offset rays).
    samples : shadow rays per point for soft emitters (area, emissive, world, sun with
        an angle, point/spot with a radius), stratified; hard point lights and a sun
        without angle use one ray. Typical 16 (``BakeSettings.direct_samples``).
    rng : random stream for this chunk.
    edge_rng : with it, also the edge evidence (:func:`edge_evidence`), its probes drawn from it.
    emitters : the emitters to sum (default every one of ``scene.emitters()``).
    budget : soft lamps share ``samples`` rays per point (deviation: light-budget, :mod:`core.light_budget`).
    draws : with ``budget`` and one sample, (n,) numbers in [0, 1) by which each point draws one ray among the soft
        lamps that give it small shares instead of a ray toward each (:func:`core.light_budget.group_draws`), or None.

    Returns
    -------
    DirectResult with E (n, 3) float64 W/m^2.
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), got {p.shape}")
    n = len(p)
    n_s = unit(_shape_check(normals, n, "normals"))
    # a caller with no shading normals passes its geometric ones twice (gap walks, grid cells): one copy
    n_g = n_s if geo_normals is normals else unit(_shape_check(geo_normals, n, "geo_normals"))
    if not np.isfinite(p).all():
        raise ValueError("direct_irradiance: non-finite receiving points")
    if samples < 1:
        raise ValueError(f"direct_irradiance: samples must be >= 1, got {samples}")
    edges = edge_rng is not None
    out = DirectResult(np.zeros((n, 3)), np.zeros((n, 3)) if edges else None, np.zeros((n, 3)) if edges else None)
    if n == 0:
        return out
    emitters = scene.emitters() if emitters is None else emitters
    lamps = ()
    if budget:  # deviation: light-budget, docs/DEVIATIONS.md
        lamps, emitters = budgeted_lamps(emitters, samples, draws is not None)
    for emitter in emitters:
        if getattr(emitter, "hard", False):  # a point light of radius 0
            _trace_hard(out, caster, p, n_s, n_g, emitter)
            continue
        if not hasattr(emitter, "sample_toward"):
            raise SceneError(f"light {getattr(emitter, 'name', emitter)!r}: unsupported type {type(emitter).__name__}")
        shadow = emitter.sample_toward(caster, p, n_s, n_g, samples, rng)
        if shadow is None:  # the emitter sends nothing (no power)
            _skip_all(out, emitter.name, n)
            continue
        vis = _trace(out, caster, p, n_g, shadow)
        if edge_rng is not None:
            edge_evidence(out, caster, p, n_s, n_g, emitter, shadow, vis, edge_rng)
    if lamps and samples <= 1:
        _trace_drawn(out, caster, p, n_s, n_g, lamps, np.asarray(draws, np.float64), rng)
    elif lamps:
        _trace_budgeted(out, caster, p, n_s, n_g, lamps, samples, rng)
    if lamps and edge_rng is not None:  # their edge evidence as any soft emitter's: one ray per lamp and point
        for lamp in lamps:
            _drawn_evidence(out, caster, p, n_s, n_g, lamp, edge_rng)
    return out


def _trace_drawn(out: DirectResult, caster: RayCaster, p, n_s, n_g, lamps: tuple, draws: np.ndarray,
                 rng: np.random.Generator) -> None:
    """Add soft ``lamps``' light to ``out``: a ray per point toward each lamp that gives it a large share, and one
    toward a lamp the point's number in ``draws`` picks among the others (:func:`core.light_budget.drawn_lamps`)."""
    for part in weight_chunks(len(p), len(lamps)):
        weights = drawn_lamps(lamps, p[part], n_s[part], draws[part])
        for lamp, factor in zip(lamps, weights):
            mine = np.flatnonzero(factor > 0)
            _skip_all(out, lamp.name, (part.stop - part.start) - len(mine))
            if len(mine):
                _trace_rows(out, caster, p, n_s, n_g, lamp, part.start + mine, 1, rng, factor[mine])


def _trace_budgeted(out: DirectResult, caster: RayCaster, p, n_s, n_g, lamps: tuple, samples: int,
                    rng: np.random.Generator) -> None:
    """Add soft ``lamps``' light to ``out``, each point's rays shared among them
    (:func:`core.light_budget.sample_counts`): the points that give a lamp the same count sample it together."""
    for part in weight_chunks(len(p), len(lamps)):
        counts = sample_counts(lamps, p[part], n_s[part], samples)
        for lamp, count in zip(lamps, counts):
            for c in np.unique(count):
                _trace_rows(out, caster, p, n_s, n_g, lamp, part.start + np.flatnonzero(count == c), int(c), rng)


def _trace_rows(out: DirectResult, caster: RayCaster, p, n_s, n_g, lamp, rows: np.ndarray, samples: int,
                rng: np.random.Generator, factor: np.ndarray | None = None) -> None:
    """:func:`_trace` of ``samples`` samples of one soft ``lamp`` at the points ``rows`` of p, their weights times
    ``factor`` (one per row) if given."""
    shadow = lamp.sample_toward(caster, p[rows], n_s[rows], n_g[rows], samples, rng)
    if shadow is None:  # the lamp sends nothing
        _skip_all(out, lamp.name, len(rows))
        return
    weight = shadow.weight if factor is None else shadow.weight * factor[shadow.idx][:, None]
    _trace(out, caster, p, n_g, replace(shadow, idx=rows[shadow.idx], weight=weight), among=len(rows))


def edge_evidence(out: DirectResult, caster: RayCaster, p, n_s, n_g, emitter, shadow: ShadowSamples,
                  vis: np.ndarray, rng: np.random.Generator) -> None:
    """Add one emitter's share of the edge evidence at points p to ``out.edge_lit`` and ``out.edge_open``
    (deviation: direct-footprint, which re-integrates texels whose samples' evidence disagrees).

    The evidence must not be the estimate E keeps: a texel judged on its own noisy samples is
    re-integrated when they came out unequal and keeps them when they came out equal, which for a
    soft emitter mostly hidden (the sky through a window: a room's walls read 0.86 of Cycles) keeps
    the unlucky zeros and redraws the lucky hits. So an exact emitter (``shadow.exact``: its one ray
    is its visibility) gives its own samples ``vis`` (k, m); a soft one, one ray per point drawn from
    ``rng``; the world none: its light has no edge, a wall's foot darkens it smoothly.
    """
    if shadow.kind == "world":
        return
    if not shadow.exact:
        _drawn_evidence(out, caster, p, n_s, n_g, emitter, rng)
        return
    _add_evidence(out, shadow, vis)


def _drawn_evidence(out: DirectResult, caster: RayCaster, p, n_s, n_g, emitter, rng: np.random.Generator) -> None:
    """:func:`edge_evidence` of a soft emitter: one ray per point drawn from ``rng``."""
    shadow = emitter.sample_toward(caster, p, n_s, n_g, 1, rng)
    if shadow is None:
        return
    vis = _visibility(caster, p, n_g, shadow)
    out.shadow_rays[shadow.kind] += int(shadow.ok.sum())
    _add_evidence(out, shadow, vis)


def _add_evidence(out: DirectResult, shadow: ShadowSamples, vis: np.ndarray) -> None:
    unoccluded = np.where(shadow.ok, shadow.weight, 0.0)
    _accumulate(out.edge_lit, shadow, unoccluded * vis)
    _accumulate(out.edge_open, shadow, unoccluded)


# --------------------------------------------------------------------------- helpers
def _shape_check(a, n, name):
    a = np.asarray(a, dtype=np.float64)
    if a.shape != (n, 3):
        raise ValueError(f"{name} must be ({n}, 3), got {a.shape}")
    return a if np.isfinite(a).all() else np.nan_to_num(a)  # the check: 4 us for 9k normals, the copy 29


def _trace(out: DirectResult, caster: RayCaster, p, n_g, shadow: ShadowSamples, among: int | None = None
           ) -> np.ndarray:
    """Trace the shadow rays of accepted samples, add colour * mean(weight * transmittance) to out.E[idx]
    and return the transmittances (k, m). among : the points the samples were drawn for (default all of p):
    those that cast no ray count as skipped."""
    vis = _visibility(caster, p, n_g, shadow)
    traced = int(np.count_nonzero(shadow.ok.any(axis=1)))  # idx holds each point once
    out.shadow_rays[shadow.kind] += int(shadow.ok.sum())
    out.skipped[shadow.key] = out.skipped.get(shadow.key, 0) + (len(p) if among is None else among) - traced
    _accumulate(out.E, shadow, np.where(shadow.ok, shadow.weight, 0.0) * vis)
    return vis


def _trace_hard(out: DirectResult, caster: RayCaster, p, n_s, n_g, light) -> None:
    """:func:`_trace` of a point light of radius 0 (``light.hard``), and :func:`edge_evidence` when ``out`` keeps
    it, the same sums in the same order without the (k, m) sample arrays: its rays from ``light.shadow_rays``
    (:func:`~core.lights.point_light_rays`). The light is exact: its one ray is each point's lit share."""
    P = _rgb(light.power, light.name)
    if not np.any(P > 0):
        _skip_all(out, light.name, len(p))
        return
    rows, weight, start, directions, t_max, lit = light.shadow_rays(p, n_s, n_g, caster.epsilon)
    vis = np.where(lit, caster.transmittance(start, directions, t_max, unit=True), 0.0)
    out.shadow_rays["point"] += len(rows)
    out.skipped[light.name] = out.skipped.get(light.name, 0) + len(p) - len(rows)
    lib = native_kernels.library()
    if lib is None:
        _add_hard_light_numpy(out, rows, P, weight, vis)
    else:
        native_kernels.add_hard_light(lib, out.E, out.edge_lit, out.edge_open, rows, P, weight, vis)


def _add_hard_light_numpy(out: DirectResult, rows: np.ndarray, P: np.ndarray, weight: np.ndarray, vis: np.ndarray
                          ) -> None:
    """A point light of colour P's light at the points ``rows`` (distinct) of ``out``, weight x transmittance
    each, added to E and, when ``out`` keeps it, to the edge evidence (the compiled kernel's reference)."""
    lit_light = P * (weight * vis)[:, None]
    out.E[rows] += lit_light
    if out.edge_lit is not None:
        out.edge_lit[rows] += lit_light
        out.edge_open[rows] += P * weight[:, None]


def _visibility(caster: RayCaster, p, n_g, shadow: ShadowSamples) -> np.ndarray:
    """(k, m) transmittance of each accepted sample's shadow ray (0 for the others)."""
    idx, ok = shadow.idx, shadow.ok
    rows, cols = np.nonzero(ok)
    vis = np.zeros(ok.shape)
    if len(rows):
        pi, ni = np.take(p, idx[rows], axis=0), np.take(n_g, idx[rows], axis=0)
        # Transmissive layers pass their share of the light (deviation: transparent-shadows).
        if shadow.directions is None:
            vis[rows, cols] = caster.transmittance_between(pi, ni, shadow.targets[rows, cols], None)
        else:
            vis[rows, cols] = caster.transmittance(pi, shadow.directions[rows, cols], np.inf, ni)
    return vis


def _accumulate(E: np.ndarray, shadow: ShadowSamples, contribution: np.ndarray) -> None:
    """E[idx] += colour x the samples' mean ``contribution`` (k, m)."""
    if shadow.colour.ndim == 3:  # a colour per sample (emissive triangles of different radiance)
        E[shadow.idx] += (contribution[..., None] * shadow.colour).sum(axis=1) / shadow.samples
    else:
        E[shadow.idx] += shadow.colour * (contribution.sum(axis=1) / shadow.samples)[:, None]


def _skip_all(out: DirectResult, key: str, n: int):
    out.skipped[key] = out.skipped.get(key, 0) + n


def shade_direct(scene: Scene, caster: RayCaster, p: np.ndarray, n_shading: np.ndarray, n_geometric: np.ndarray,
                 samples: int, seed: int, stream, executor, progress, whole: bool = False, budget: bool = False,
                 draws: np.ndarray | None = None) -> tuple[np.ndarray | DirectResult, dict]:
    """Direct irradiance (n, 3) at surface points, chunked over the executor, plus summed work counters.

    stream : int or sequence of ints after ``seed`` in each chunk's generator
        ``default_rng([seed, *stream, chunk])`` (core/constants.py lists the streams).
    whole : return the merged :class:`DirectResult` with the edge evidence (:func:`edge_evidence`, its
        probes from ``[seed, *stream, chunk, STREAM_DIRECT_EDGE]``) instead of its E.
    budget : soft lamps share the samples (deviation: light-budget, :func:`direct_irradiance`).
    draws : (n,) each point's number for drawing a soft lamp, as :func:`direct_irradiance` takes it, or None.
    """
    serial = caster.serial()
    prefix = [seed, *np.atleast_1d(stream).tolist()]

    def run(index, s):
        rng = np.random.default_rng([*prefix, index])
        edge_rng = np.random.default_rng([*prefix, index, STREAM_DIRECT_EDGE]) if whole else None
        n_s = n_shading[s]
        n_g = n_s if n_geometric is n_shading else n_geometric[s]  # one set of normals stays one
        return direct_irradiance(scene, serial, p[s], n_s, n_g, samples, rng, edge_rng, budget=budget,
                                 draws=None if draws is None else draws[s])

    # A chunk's arrays hold points x samples rays: past 16 samples the chunks shrink to keep them the size
    # they are at 16 (256 samples at full chunks would need ~3 GB on two workers).
    chunk = max(1, TEXEL_CHUNK * 16 // max(int(samples), 16))
    merged = DirectResult.concatenate(executor.map_chunks(run, slices(len(p), chunk), progress))
    counters = {f"shadow_rays_{k}": v for k, v in merged.shadow_rays.items()}
    counters["shadow_rays"] = sum(merged.shadow_rays.values())
    counters["shadow_rays_skipped_points"] = sum(merged.skipped.values())
    for light, skipped in merged.skipped.items():  # points that cast no ray toward this emitter
        counters[f"shadow_rays_skipped_points:{light}"] = skipped
    caster.rays_cast += counters["shadow_rays"]
    return (merged if whole else merged.E), counters
