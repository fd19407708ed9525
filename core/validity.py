"""Texel validity: is a texel sample inside closed geometry?

deviation: texel-validity, docs/DEVIATIONS.md (switch ``Deviations.texel_validity``).

Texels under an object resting on a surface (a box without a bottom on a
floor) or in a gap thinner than the records' zones (a lamp panel just below
a ceiling) see only back faces. No light reaches them, but Ward's
interpolation would happily carry a neighbouring record's irradiance in
(a light leak: 24 % indirect RMSE on the Cornell floor and ceiling without
this test). A few hemisphere rays per sample tell them apart, as in
production light mappers: a sample whose rays mostly hit back faces is
inside geometry and receives no indirect light and no hole record.

The rays are cast in rounds and a sample leaves as soon as its verdict
cannot change: a sample whose first four rays (of eight) see no back face
can no longer reach a majority, which is most samples in most scenes. The
verdict is the one all eight rays would give; only the ray count drops
(Cornell at 512x512: 25.3 M rays to 14.3 M).
"""
from __future__ import annotations

import numpy as np

from .constants import (BACKFACE_FRACTION, COVERED_COS, COVERED_TEXELS, EVIDENCE_COS, EVIDENCE_PHOTONS,
                        EVIDENCE_REACH, STREAM_VALIDITY, STREAM_VALIDITY_FOOTPRINT, VALIDITY_FOOTPRINT_PER_AXIS,
                        VALIDITY_RAYS)
from .executor import TEXEL_CHUNK, Executor, slices
from .rays import RayCaster
from .sampling import cosine_directions
from .texels import footprint_texel_points

LATER_ROUND = 2
"""Rays per sample in each round after the first."""


def inside_geometry(caster: RayCaster, face_normals: np.ndarray, p: np.ndarray, n: np.ndarray,
                    rng: np.random.Generator, rays: int = VALIDITY_RAYS, cover: float = 0.0,
                    open_back: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """(inside (m,) bool: samples that see mostly back faces; covered (m,) bool: samples whose first
    round of rays all hit, nearer than ``cover``, a face turned back toward them (none when 0); the
    rays cast).

    p, n : (m, 3) sample positions and geometric normals (front side).
    face_normals : (T, 3) unit geometric normals of the scene's triangles.
    open_back : (T,) bool triangles whose back is open space (lit mostly from behind: a wall whose normals
        point the wrong way, :func:`open_backs`); meeting their back is no sign of being inside. None: every
        back counts.
    A covered sample lies in a gap a fraction of a texel high (a floor a slab rests on 1 mm above):
    light reaches it only past the gap's far edges and no camera sees it, whichever way the faces
    point; Ward's weights would carry the open floor's light in (Sponza 16/m: 168 interior texels
    whose eight rays all hit within 5 mm, Cycles 0.0073 there, PDIC 0.15).
    A pure function of its chunk: the executor runs it over chunks of samples.
    """
    m = len(p)
    inside = np.zeros(m, bool)
    covered = np.zeros(m, bool)
    if m == 0:
        return inside, covered, 0
    majority = int(np.floor(BACKFACE_FRACTION * rays)) + 1  # back hits that make a sample inside
    # All random numbers are drawn up front, so the verdict does not depend on the round schedule;
    # directions are made only for the rays a round casts (most samples settle after the first).
    u = rng.random((m, rays, 2))
    back = np.zeros(m, np.int64)
    open_ = np.arange(m)  # samples whose verdict is still open
    cast, done = 0, 0
    first = rays - majority + 1  # the fewest rays after which "no back face yet" settles "outside"
    while len(open_) and done < rays:
        step = min(first if done == 0 else LATER_ROUND, rays - done)
        ray_sample = np.repeat(open_, step)
        n_ray = np.take(n, ray_sample, axis=0)
        d = cosine_directions(u[open_, done:done + step].reshape(-1, 2), n_ray)
        hits = caster.intersect(np.take(p, ray_sample, axis=0), d, normals=n_ray, unit=True)
        cast += len(d)
        hit = hits.hit
        is_back = np.zeros(len(d), bool)
        is_back[hit] = closed_backs(face_normals, hits.triangle[hit], d[hit], open_back)
        back[open_] += is_back.reshape(-1, step).sum(axis=1)
        if done == 0 and cover > 0:
            under = _under_cover(hits, face_normals, n_ray, cover)
            covered = under.reshape(-1, step).all(axis=1)  # the first round asks every sample
        done += step
        b = back[open_]
        settled_inside = b >= majority
        settled_outside = b + (rays - done) < majority
        inside[open_[settled_inside]] = True
        open_ = open_[~(settled_inside | settled_outside)]
    return inside, covered, cast


def closed_backs(face_normals: np.ndarray, triangle: np.ndarray, direction: np.ndarray,
                 open_back: np.ndarray | None = None) -> np.ndarray:
    """(r,) bool: rays ``direction`` (r, 3) that met ``triangle`` (r,) from behind, the back-face votes'
    evidence of being inside a solid; the backs of ``open_back`` triangles do not count."""
    back = np.einsum("ij,ij->i", np.take(face_normals, triangle, axis=0), direction) > 0
    if open_back is not None:
        back &= ~np.take(open_back, triangle)
    return back


def _under_cover(hits, face_normals: np.ndarray, n: np.ndarray, cover: float) -> np.ndarray:
    """(r,) bool: rays from samples facing n (r, 3) that hit, nearer than ``cover``, a face turned back
    toward the sample (COVERED_COS): a sheet over it, not the far side of a corner, which may be lit.

    Distance, not height above the sample: a ray leaving at angle theta from the normal meets a sheet
    h above at h / cos(theta), so only a sheet reaching well past the sample on every side stops all of
    them (under a sheet of width w, about (h / w)^2 of the light gets in). The cathedral's window
    tracery, 2 cm before a wall and 6 cm wide, is lit there nearly as the open wall is (Cycles 0.105
    against 0.096), and a height test called it covered (PDIC 0.54 of Cycles)."""
    near = np.zeros(len(n), bool)
    hit = np.flatnonzero(hits.hit & (hits.t < cover))
    facing = np.einsum("ij,ij->i", np.take(face_normals, hits.triangle[hit], axis=0), n[hit])
    near[hit] = facing < -COVERED_COS
    return near


def texel_validity(caster: RayCaster, points, seed: list, executor, progress, cover: float = 0.0,
                   open_back: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Which texel samples lie inside closed geometry, chunked over the executor: :func:`inside_geometry`'s
    (inside (n,) bool, covered (n,) bool, rays cast).

    points : :class:`core.texels.TexelPoints`. seed : the generator prefix; chunk i draws from
    ``default_rng([*seed, i])``. open_back : as :func:`inside_geometry`'s.
    """
    serial = caster.serial()

    def run(index, s):
        return inside_geometry(serial, serial.face_normals, points.p[s], points.n_geometric[s],
                               np.random.default_rng([*seed, index]), cover=cover, open_back=open_back)

    parts = executor.map_chunks(run, slices(len(points), TEXEL_CHUNK), progress)
    rays = sum(r for *_, r in parts)
    caster.rays_cast += rays
    inside = np.concatenate([i for i, _, _ in parts]) if parts else np.zeros(0, bool)
    covered = np.concatenate([c for _, c, _ in parts]) if parts else np.zeros(0, bool)
    return inside, covered, rays


def sample_validity(scene, caster: RayCaster, density, target_index: int, points, texel_size: float, stream: int,
                    R_min: float, settings, executor, progress, stats, voted: np.ndarray | None = None,
                    contact=None, centre_triangle: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One target's texel validity: (inside (n,) bool, each sample's share of its texel's light (n,),
    :func:`indirect_weights`), its counters added to ``stats`` (stage ``validity``).

    The back-face vote (:func:`texel_validity`), less photon evidence, or covered (:func:`verdict`);
    density None (no photons) leaves the evidence out. voted : (n,) bool the samples to vote on (the
    rest count as outside: a bake without indirect light), or None for all. contact : the scene's
    :class:`core.contact.ContactFaces` (deviations: contact-faces, under-sheets): samples on a face another
    touches face to face or under a sheet are covered; or None. centre_triangle : the target's
    :attr:`core.texels.TargetRaster.centre_triangle` (:func:`indirect_weights`), or None.
    """
    progress.begin("Texel validity")
    inside, covered, rays = np.zeros(len(points), bool), np.zeros(len(points), bool), 0
    with stats.stage("validity"):
        cover = COVERED_TEXELS * texel_size
        if settings.deviations.texel_validity:  # deviation: texel-validity, docs/DEVIATIONS.md
            asked = points if voted is None else points.take(np.flatnonzero(voted))
            vote, cast, rays = texel_validity(caster, asked, [settings.seed, STREAM_VALIDITY, stream], executor,
                                              progress, cover, open_backs(caster, density, settings.deviations))
            if voted is None:
                inside, covered = vote, cast
            else:
                inside[voted], covered[voted] = vote, cast
        none = np.zeros(len(points), bool)
        touching = none if contact is None else contact.touching(points.p, points.triangle)
        sheet = none if contact is None else contact.under_sheet(points.p, points.triangle)
        covered |= touching | sheet
        inside, overruled = verdict(inside, covered, caster, density, points.p, points.n_geometric, R_min, settings)
        weights, footprint_rays = indirect_weights(scene, caster, density, target_index, points, inside, settings,
                                                   R_min, stream, cover, executor, progress, contact,
                                                   centre_triangle)
    stats.add(texel_samples_inside_geometry=int(inside.sum()), validity_rays=rays + footprint_rays,
              texel_samples_photon_evidence=overruled, texel_samples_covered=int(covered.sum()),
              texel_samples_in_contact=int(touching.sum()), texel_samples_under_sheet=int(sheet.sum()))
    return inside, weights


def open_backs(caster: RayCaster, density, deviations) -> np.ndarray | None:
    """(T,) bool triangles the back-face votes do not count as a solid's inside, or None (count all):
    those lit mostly on their back (deviation: photon-evidence), a wall modelled with its normals
    flipped, which Cycles lights on both sides. No photon lands on the inside of a closed solid, but
    one may slip through a crack onto the back of a front-lit face: Sponza has 612 triangles with a
    photon on their back (945 photons of 2.85 M), most of them on walls lit from the front."""
    if deviations.photon_evidence and density is not None:
        return density.back_lit_faces(caster.face_normals)
    return None


def verdict(inside: np.ndarray, covered: np.ndarray, caster: RayCaster, density, p: np.ndarray, n: np.ndarray,
            R_min: float, settings) -> tuple[np.ndarray, int]:
    """(m,) bool samples inside geometry, and how many votes photons overruled: :func:`inside_geometry`'s
    back-face vote ``inside`` less what photon evidence overrules (deviation: photon-evidence; the vote
    is changed in place), or ``covered`` (photons that reach a gap's floor do not make it seen or lit
    like the open floor). p, n : (m, 3) the samples and their front-side normals; density None: a bake
    without photons, no evidence."""
    overruled = 0
    if settings.deviations.photon_evidence and density is not None:  # deviation: photon-evidence, docs/DEVIATIONS.md
        overruled = overrule_by_photons(inside, caster, density, p, n, R_min)
    return inside | covered, overruled


def overrule_by_photons(inside: np.ndarray, caster: RayCaster, density, p: np.ndarray, n: np.ndarray,
                        R_min: float) -> int:
    """Clear ``inside`` (m,) bool, a back-face vote's verdicts on points p facing n (m, 3), where
    :func:`reached_by_photons` finds light reaching them; returns how many (deviation: photon-evidence)."""
    voted = np.flatnonzero(inside)
    reached = voted[reached_by_photons(caster, density, p[voted], n[voted], R_min)]
    inside[reached] = False
    return len(reached)


def reached_by_photons(caster: RayCaster, density, p: np.ndarray, n: np.ndarray, R_min: float) -> np.ndarray:
    """(m,) bool: did a photon arrive within EVIDENCE_REACH R_min of p, on a surface facing as n does
    (EVIDENCE_COS) whose side sees the side of p that n faces? (deviation: photon-evidence)

    The back-face votes read a mesh's normals, which a user's model often has pointing the wrong way
    on whole walls; Cycles shades both sides alike and lights what such a wall faces. A photon that
    arrived nearby and can see the point proves light reaches it, whatever the normals say. Asks the
    EVIDENCE_PHOTONS nearest photons, one occlusion ray per photon within reach.
    p, n : (m, 3) points and their front-side normals; density : :class:`core.density.PhotonDensity`.
    """
    m = len(p)
    reached = np.zeros(m, bool)
    photons = len(density.p)
    if m == 0 or photons == 0:
        return reached
    k = min(EVIDENCE_PHOTONS, photons)
    dist, idx = density.tree.query(p, k=k, distance_upper_bound=EVIDENCE_REACH * R_min, workers=density.workers)
    dist, idx = dist.reshape(m, k), idx.reshape(m, k)
    point, photon = np.nonzero(np.isfinite(dist))
    q_n = np.take(density.n, idx[point, photon], axis=0).astype(np.float64)
    alike = np.einsum("ij,ij->i", q_n, np.take(n, point, axis=0)) > EVIDENCE_COS
    point, photon, q_n = point[alike], photon[alike], q_n[alike]
    if len(point) == 0:
        return reached
    q = np.take(density.p, idx[point, photon], axis=0).astype(np.float64)
    seen = caster.sides_visible(np.take(p, point, axis=0), np.take(n, point, axis=0), q, q_n)
    reached[point[seen]] = True
    return reached


def indirect_weights(scene, caster, density, target_index: int, points, inside: np.ndarray, settings, R_min: float,
                     stream: int, cover: float = 0.0, executor=None, progress=None, contact=None,
                     centre_triangle: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Each texel sample's share of its texel's indirect light, (n,) float64, and the rays cast.

    Samples inside geometry get none. A texel whose samples straddle a solid's boundary (a floor
    texel at a wall's foot: some samples under the wall) holds the outside samples' mean times the
    share of its footprint outside, as Cycles' bake does, whose jittered points inside the wall
    find no light: the 2x2 samples alone would make that share 0 or 1/2 where it is anything in
    between (the occluded building at 4 texels/m: texels 1 cm from a wall at half of Cycles' light
    or twice it). The share is voted at VALIDITY_FOOTPRINT_PER_AXIS^2 jittered points over the
    footprint Cycles integrates (``settings.direct_footprint_side``), as the samples are
    (:func:`texel_validity`, chunked over ``executor``, one thread if None); ``cover``: as
    :func:`inside_geometry`'s, points that near under a surface count as inside; ``contact``: as
    :func:`sample_validity`'s, points on a touching face count as inside; ``centre_triangle``: the target's
    :attr:`core.texels.TargetRaster.centre_triangle`, off which the jittered points are dropped
    (deviation: crease-folding), or None.
    """
    w = points.weight.astype(np.float64)
    if not inside.any():
        return w, 0
    size = int(points.texel.max()) + 1
    total = np.bincount(points.texel, weights=w, minlength=size)
    kept = np.bincount(points.texel, weights=np.where(inside, 0.0, w), minlength=size)
    outside_share = kept / np.maximum(total, 1e-30)
    straddling = np.flatnonzero((kept > 0) & (kept < total))
    rng = np.random.default_rng([settings.seed, STREAM_VALIDITY_FOOTPRINT, stream])
    fp = footprint_texel_points(scene, target_index, straddling, VALIDITY_FOOTPRINT_PER_AXIS, rng,
                                settings.direct_footprint_side,
                                centre_triangle if settings.deviations.crease_folding else None)
    rays = 0
    if len(fp):
        fp_inside, fp_covered, rays = texel_validity(caster, fp, [settings.seed, STREAM_VALIDITY_FOOTPRINT, stream, 1],
                                                     executor if executor is not None else Executor(1), progress,
                                                     cover, open_backs(caster, density, settings.deviations))
        if contact is not None:  # deviations: contact-faces, under-sheets, docs/DEVIATIONS.md
            fp_covered |= contact.samples(fp.p, fp.triangle)
        fp_inside, _ = verdict(fp_inside, fp_covered, caster, density, fp.p, fp.n_geometric, R_min, settings)
        fw = fp.weight.astype(np.float64)
        fp_total = np.bincount(fp.texel, weights=fw, minlength=size)
        fp_out = np.bincount(fp.texel, weights=np.where(fp_inside, 0.0, fw), minlength=size)
        reached = fp_total > 0  # a sliver the jittered points all missed keeps its samples' share
        outside_share[reached] = fp_out[reached] / fp_total[reached]
    scale = np.divide(total * outside_share, kept, out=np.zeros(size), where=kept > 0)
    return np.where(inside, 0.0, w * scale[points.texel]), rays
