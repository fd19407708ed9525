"""Density control of the photon map (paper section 3.4, Equation 4; [SW00]'s power redistribution).

Record k's zone of influence covers at least pi (a R_k)^2 of surface, so a map that should hold
at most ``n`` photons per zone needs at most

    D_kmax = n / (pi (a R_k)^2)          photons per unit area around k (Equation 4)

The paper prints Equation 4 as n / (a R_k); the pi (a R_k)^2 area its text derives is what makes
it a density (docs/DEVIATIONS.md). Where R_k is small (corners, complex visibility) many photons
stay; where R_k is large few do. This is the paper's second variant, run after pass 1 on the
stored photons::

    for each stored photon i (direct and indirect photons apart):
        R_i  <- Figure 3's harmonic mean of last-hit distances of its r nearest indirect photons,
                in [R_min, R_max]
        D_i  <- r / (pi rho_r^2), rho_r the distance to its r-th nearest photon of its class
        keep i with probability min(1, D_max(R_i) / D_i)
    each discarded photon's power goes, in equal shares, to its nearest kept photons of the same
    class on the same surface [SW00]; a photon with none is kept after all (power is conserved)
    a path link (``prev``) to a discarded photon moves to its nearest receiver, whose radiance
    stands in for it in pass 3's virtual rays; ``wi`` and ``d_prev`` still name the true last hit
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy.spatial import cKDTree

from .constants import (DENSITY_RECEIVERS, R_K_DISTANCE_FLOOR, R_K_SAME_SIDE_COS, SAME_SURFACE_COS,
                        STREAM_DENSITY_CONTROL)
from .photons import PhotonMap
from .vectors import norms

_CHUNK = 65_536
"""Photons per kd-tree query batch (bounds the (chunk, r) neighbour arrays to a few MB)."""


@dataclass(frozen=True)
class DensityControlStats:
    stored: int
    """Photons before control."""
    kept: int
    """Photons after control."""
    redistributed: int
    """Discarded photons whose power went to kept neighbours."""
    unplaced: int
    """Photons chosen for discarding that had no kept neighbour on their surface, so stayed."""


def harmonic_last_hit_radius(p: np.ndarray, n: np.ndarray, photons: PhotonMap, r_nearest: int,
                             R_min: float, R_max: float) -> np.ndarray:
    """(m,) float64 R at points ``p`` (m, 3) with normals ``n``: Figure 3's harmonic mean of
    |p_lh - p| over the ``r_nearest`` nearest indirect photons facing the same way, in [R_min, R_max]."""
    indirect = np.flatnonzero(photons.is_indirect)
    R = np.full(len(p), R_max)
    if len(indirect) == 0:
        return R
    tree = cKDTree(photons.p[indirect].astype(np.float64))
    last_hit, normals = photons.last_hit[indirect], photons.n[indirect].astype(np.float64)
    k = min(r_nearest, len(indirect))
    for s in range(0, len(p), _CHUNK):
        P, N = p[s:s + _CHUNK].astype(np.float64), n[s:s + _CHUNK].astype(np.float64)
        _, idx = tree.query(P, k=k, workers=-1)
        idx = idx.reshape(len(P), k)
        to_hit = last_hit[idx] - P[:, None, :]
        ok = (np.einsum("mkj,mj->mk", normals[idx], N) > R_K_SAME_SIDE_COS) & (np.einsum("mkj,mj->mk", to_hit, N) > 0)
        d = np.maximum(norms(to_hit), R_K_DISTANCE_FLOOR * R_max)
        count, inv = ok.sum(axis=1), np.where(ok, 1.0 / d, 0.0).sum(axis=1)
        R[s:s + len(P)] = np.where(count > 0, count / np.maximum(inv, 1e-300), R_max)
    return np.clip(R, R_min, R_max)


def keep_probability(photons: PhotonMap, members: np.ndarray, R: np.ndarray, n: int, a: float,
                     r_nearest: int) -> np.ndarray:
    """(m,) float64 min(1, D_max / D) for the photons ``members`` (one class), R (m,) at each.

    D = r / (pi rho_r^2) from the distance rho_r to the r-th nearest other member;
    D_max = n / (pi (a R)^2) (Equation 4).
    """
    if len(members) <= 1:
        return np.ones(len(members))
    k = min(r_nearest + 1, len(members))  # the photon itself is its own nearest
    tree = cKDTree(photons.p[members].astype(np.float64))
    rho = np.empty(len(members))
    for s in range(0, len(members), _CHUNK):
        dist, _ = tree.query(tree.data[s:s + _CHUNK], k=k, workers=-1)
        rho[s:s + len(dist)] = dist.reshape(len(dist), k)[:, -1]
    D = (k - 1) / (np.pi * np.maximum(rho, 1e-300) ** 2)
    D_max = n / (np.pi * (a * R) ** 2)  # Equation 4
    return np.minimum(1.0, D_max / D)


def redistribute(photons: PhotonMap, members: np.ndarray, drop: np.ndarray, power: np.ndarray,
                 receiver: np.ndarray) -> np.ndarray:
    """Give the power of ``members[drop]`` to their nearest kept members on the same surface [SW00].

    power : (N, 3) float64, updated in place. receiver : (N,) int64, set to the nearest receiver
    of each discarded photon. Returns (m,) bool: the members actually discarded (those with no
    kept neighbour on their surface stay).
    """
    kept = members[~drop]
    gone = members[drop]
    if len(kept) == 0 or len(gone) == 0:
        return np.zeros(len(members), bool)
    k = min(DENSITY_RECEIVERS, len(kept))
    tree = cKDTree(photons.p[kept].astype(np.float64))
    placed = np.zeros(len(gone), bool)
    for s in range(0, len(gone), _CHUNK):
        g = gone[s:s + _CHUNK]
        _, idx = tree.query(photons.p[g].astype(np.float64), k=k, workers=-1)
        idx = idx.reshape(len(g), k)
        same = np.einsum("mkj,mj->mk", photons.n[kept[idx]].astype(np.float64), photons.n[g].astype(np.float64)) \
            >= SAME_SURFACE_COS
        shares = same.sum(axis=1)
        ok = shares > 0
        rows, cols = np.nonzero(same[ok])
        share = power[g[ok]] / shares[ok][:, None]
        np.add.at(power, kept[idx[ok][rows, cols]], share[rows])
        receiver[g[ok]] = kept[idx[ok][np.arange(ok.sum()), same[ok].argmax(axis=1)]]
        placed[s:s + len(g)] = ok
    discarded = np.zeros(len(members), bool)
    discarded[np.flatnonzero(drop)[placed]] = True
    return discarded


def control_density(photons: PhotonMap, n: int, a: float, r_nearest: int, R_min: float, R_max: float,
                    seed: int) -> tuple[PhotonMap, DensityControlStats]:
    """Thin ``photons`` to at most ~``n`` per record zone (Equation 4), conserving their power.

    n : most photons wanted in a zone of influence (typical 16-64). a, r_nearest, R_min, R_max :
    the cache's parameters (R_k's estimate and bounds, in scene units).
    Returns the controlled map (a new value; ``emitted`` unchanged) and counters.
    """
    N = len(photons)
    if N == 0:
        return photons, DensityControlStats(0, 0, 0, 0)
    rng = np.random.default_rng([seed, STREAM_DENSITY_CONTROL])
    R = harmonic_last_hit_radius(photons.p, photons.n, photons, r_nearest, R_min, R_max)
    power = photons.power.astype(np.float64)
    receiver = np.arange(N, dtype=np.int64)
    discarded = np.zeros(N, bool)
    wanted = 0
    for members in (np.flatnonzero(~photons.is_indirect), np.flatnonzero(photons.is_indirect)):
        drop = rng.random(len(members)) >= keep_probability(photons, members, R[members], n, a, r_nearest)
        wanted += int(drop.sum())
        discarded[members] = redistribute(photons, members, drop, power, receiver)
    controlled = _without(photons, discarded, power.astype(np.float32), receiver)
    gone = int(discarded.sum())
    return controlled, DensityControlStats(N, N - gone, gone, wanted - gone)


def _without(photons: PhotonMap, discarded: np.ndarray, power: np.ndarray, receiver: np.ndarray) -> PhotonMap:
    """The map without the ``discarded`` photons; path links to them follow ``receiver``."""
    kept = np.flatnonzero(~discarded)
    new_index = np.full(len(photons), -1, np.int64)
    new_index[kept] = np.arange(len(kept))
    new_index = new_index[receiver]  # a discarded photon's links land on its receiver
    columns = {f.name: getattr(photons, f.name)[kept] for f in fields(photons) if f.name != "emitted"}
    prev = photons.prev[kept].astype(np.int64)
    columns["prev"] = np.where(prev >= 0, new_index[np.maximum(prev, 0)], -1).astype(np.int32)
    columns["power"] = power[kept]
    return PhotonMap(**columns, emitted=photons.emitted)


def controlled_pass(photons: PhotonMap, params, settings, progress, stats) -> PhotonMap:
    """Density control as a bake step after pass 1 (``params``: the CacheParameters; ``stats``:
    a BakeStats); the map unchanged when ``settings.density_control`` is 0."""
    if not settings.density_control or len(photons) == 0:
        return photons
    progress.begin("Pass 1: density control")
    with stats.stage("density_control"):
        controlled, counts = control_density(photons, settings.density_control, params.a, params.r_nearest,
                                             params.R_min, params.R_max, settings.seed)
    stats.set(photons_stored=counts.kept, photons_before_control=counts.stored,
              photons_redistributed=counts.redistributed, photons_unplaced=counts.unplaced,
              photon_bytes=controlled.nbytes)
    return controlled
