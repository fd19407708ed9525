"""The bake manifest: ``pdic_manifest.json``, written next to the light-map images.

Pure json, bpy-free. A game engine, a script or a test reads the manifest to
find each object's light map, the UV map it is laid out in, how it was baked
and how long that took. Keys are written in a fixed order (top level and per
object as listed below; ``settings`` and ``stats`` sorted recursively), so two
bakes of the same scene give diffable files.

Schema (``schema_version`` 1)
-----------------------------
``schema_version`` : int
    1. Bumped when a key changes meaning or disappears (adding keys does not bump it).
``generator`` : str
    ``"pdic <version>"``.
``units`` : str
    What a texel holds: ``"irradiance/pi"`` - irradiance E divided by pi, in
    Blender's light units (W/m^2/sr, i.e. the radiance a white diffuse surface
    reflects; Cycles' Diffuse bake, Direct+Indirect, no Color). Multiply by the
    albedo to get outgoing radiance.
``objects`` : list of dict, one per baked object, in bake order:
    ``name`` : str, the Blender object name.
    ``image`` : str, path of the light-map image relative to the manifest's
        folder (POSIX separators), e.g. ``"PDIC_Cube.exr"``; ``""`` if the image
        was packed into the .blend instead.
    ``image_name`` : str, the Blender image datablock (``"PDIC_<object>"``).
    ``uv_map`` : str, the mesh UV map the light map is laid out in (``"PDIC_Lightmap"``).
    ``width``, ``height`` : int, resolution in texels.
    ``format`` : str, ``"OPEN_EXR"``; ``color_depth`` : str, ``"16"`` (half) or ``"32"`` (float).
    ``color_space`` : str, ``"Non-Color"`` (linear values, no transform).
    ``channels`` : str, ``"RGBA"``: linear RGB irradiance/pi, A = texel coverage in [0, 1].
    ``blend`` : str, file name of the .blend the object belongs to (``""`` if unsaved); a
        folder may hold the maps of several .blend files, and a partial bake keeps the
        entries of the objects it did not re-bake.
    further keys (sorted) as the caller supplies them, e.g. ``texels`` (int,
    covered texels), ``charts`` (int), ``utilization`` (float, 0..1 of the square),
    ``resolution_requested`` (int, the side the surface area gives; with a Texel Density the
    map grows past it until the charts fit at that density), ``texel_density_achieved`` (float,
    texels per scene unit over the mesh's surface: at least a requested Texel Density unless the
    map would outgrow the largest light map, when the bake warns under half of it), ``uv_source``
    (str, present when the object named Light-Map UVs of its own: that UV map, whose layout ``uv_map``
    holds a copy of; ``charts`` and ``unwrap_cached`` are then absent, and ``texel_density_median``, float,
    the texels per scene unit at the area-weighted median of its triangles', is present).
``settings`` : dict
    The :class:`core.settings.BakeSettings` fields (see that module for units),
    keys sorted.
``stats`` : dict
    :meth:`core.stats.BakeStats.as_dict` plus the add-on's own stages:
    ``seconds`` (dict stage -> wall seconds, float; with indirect light on more than one thread the
    ``direct`` stage runs on a thread of its own beside passes 2-3 and the first target's texels'
    stage, and ``direct_wait`` is the time the bake then waited for it, if any; ``validity``, texel
    validity and the crevice test, likewise beside pass 2 once the photons are traced, and
    ``verdicts_wait``; ``texels``, the texels' stages of the smallest objects of a bake of several, on a
    thread of their own beside the others', and ``texels_wait``), ``seconds_beside``
    (list of the stages that ran beside others, absent when none did), ``seconds_total`` (float, s:
    the stages' sum, those beside left out), ``counters`` (dict name -> int or float: photons,
    records, rays cast/saved, texels, ...), ``kernels`` (str: how Equation 3 ran, ``"compiled (<library>)"`` or
    ``"numpy (<why not compiled>)"``, :mod:`core.native_kernels`). Keys sorted. For every stage that cast rays, ``embree_seconds_<stage>``
    (float, s: wall time inside Embree's traversal calls, summed over threads) and
    ``embree_share_<stage>`` (float in (0, 1]: that time over the stage's thread time,
    ``threads`` x its wall seconds, one thread for a stage run beside the others; e.g. ``embree_share_refine`` for pass 3; a low share means
    the stage is bound by Python/numpy, not by rays). Direct light: ``shadow_rays`` (int, at
    the regular texel samples; ``shadow_rays_<kind>`` per light kind) and, with the
    direct-footprint deviation, ``direct_footprint_texels`` (int, texels a shadow edge may cross),
    ``direct_footprint_points`` (int, jittered points over their footprints) and
    ``direct_footprint_shadow_rays`` (int, the rays those points cast). ``texels_buried`` (int,
    covered texels wholly or partly inside closed geometry, e.g. under a wall or cut by its face;
    with the buried-texels deviation on, docs/DEVIATIONS.md, they hold their whole neighbours' light).
    ``texel_samples_folded`` (int, samples placed on their texel's centre triangle for texels a triangle
    edge crosses, deviation crease-folding), ``texel_samples_past_edges`` (int, the same for texels at a chart's
    edge, deviation edge-folding).
    Texel validity: ``texel_samples_inside_geometry`` (int, samples given no indirect light),
    of them ``texel_samples_covered`` (int, samples under a sheet nearer than a tenth of a texel,
    on a face another touches face to face: ``texel_samples_in_contact``, int, deviation
    contact-faces, or under a face nearer than the rays' offset: ``texel_samples_under_sheet``, int,
    deviation under-sheets; their tests cast ``contact_rays``, int; such samples get no direct light either),
    and ``texel_samples_photon_evidence`` (int, back-face votes a photon overruled),
    ``validity_rays`` (int); a bake without indirect light votes only on unlit samples near lit
    texels, to bury texels for the light map. Pass 2: ``photons_uncovered_after_clamp`` (int, photons
    the final neighbour clamps left outside every zone, summed over the rounds that placed records
    for them, deviation clamp-recovery). Pass 3: ``refine_gap_hits`` (int, gathering hits
    in a gap before their record's surface that gathered their own indirect light, deviation
    gap-gathering; ``holes_refine_gap_hits`` for the hole records). Deviation crevice-records:
    ``crevice_samples`` (int, texel samples in crevices that gathered a record of their own),
    ``crevice_distance_rays`` (int, the rays cast to tell them: five per valid sample, cut short,
    and five more where the short ones left the verdict open) and
    ``crevice_refine_*`` (their gathering, as ``refine_*``). Deviation thin-coverage:
    ``holes_thin_samples`` (int, texel points records accepted with too little weight, which the first
    round of hole records covered too).
``warnings`` : list of str
    Everything the bake reported but did not stop for (skipped objects, clamped
    values, degenerate triangles).

Every number is finite: :func:`write_manifest` raises ``ValueError`` naming the
key if it meets NaN or infinity, so a reader never has to guard against them.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

from . import atomic

SCHEMA_VERSION = 1
FILENAME = "pdic_manifest.json"
UNITS = "irradiance/pi"
OBJECT_KEYS = ("name", "blend", "image", "image_name", "uv_map", "width", "height",
               "format", "color_depth", "color_space", "channels")
REQUIRED_OBJECT_KEYS = ("name", "image", "uv_map", "width", "height")


def _plain(value, where: str):
    """``value`` as plain json types (numpy scalars/arrays converted), rejecting non-finite numbers."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, dict):
        return {str(k): _plain(v, f"{where}.{k}") for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if hasattr(value, "tolist"):  # numpy scalar or array
        return _plain(value.tolist(), where)
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"manifest: {where} is {value!r}; every number must be finite")
        return float(value)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise ValueError(f"manifest: {where} has type {type(value).__name__}, which JSON cannot hold")


def build_manifest(objects: list, stats: dict, settings: dict, warnings: list, generator: str = "") -> dict:
    """The manifest as an ordered dict (see the module docstring); validates every value."""
    entries = []
    for i, obj in enumerate(objects):
        missing = [k for k in REQUIRED_OBJECT_KEYS if k not in obj]
        if missing:
            raise ValueError(f"manifest: object {obj.get('name', i)!r} lacks {', '.join(missing)}")
        for key in ("width", "height"):
            if not isinstance(obj[key], int) and not (hasattr(obj[key], "dtype") and obj[key].dtype.kind in "iu"):
                raise ValueError(f"manifest: objects[{i}].{key} must be an integer, got {obj[key]!r}")
        ordered = {k: _plain(obj[k], f"objects[{i}].{k}") for k in OBJECT_KEYS if k in obj}
        for k in sorted(set(obj) - set(OBJECT_KEYS), key=str):
            ordered[str(k)] = _plain(obj[k], f"objects[{i}].{k}")
        entries.append(ordered)
    if not generator:
        from . import __version__
        generator = f"pdic {__version__}"
    return {
        "schema_version": SCHEMA_VERSION,
        "generator": generator,
        "units": UNITS,
        "objects": entries,
        "settings": _plain(dict(settings), "settings"),
        "stats": _plain(dict(stats), "stats"),
        "warnings": [str(w) for w in warnings],
    }


def write_manifest(path, objects: list, stats: dict, settings: dict, warnings: list) -> Path:
    """Write ``pdic_manifest.json`` and return its path.

    Parameters
    ----------
    path : the output folder (the file is ``<path>/pdic_manifest.json``) or a path
        ending in ``.json``.
    objects : one dict per baked object with at least ``name``, ``image``
        (path relative to the manifest's folder), ``uv_map``, ``width``, ``height``.
    stats, settings : JSON-serialisable dicts (numpy scalars are converted).
    warnings : messages.

    Raises
    ------
    ValueError : a NaN/inf number, a missing object key or a non-JSON value (named).
    OSError : the file cannot be written (nothing is left behind).
    """
    path = Path(path)
    if path.suffix.lower() != ".json":
        path = path / FILENAME
    document = build_manifest(objects, stats, settings, warnings)
    text = json.dumps(document, indent=2, allow_nan=False) + "\n"
    return atomic.write_text_atomic(path, text)


def merge_objects(previous: list, baked: list, still_in_use) -> list:
    """The manifest's object list after a partial bake: ``baked`` plus the previous entries still in use.

    previous : the entries of the manifest already in the folder (may be empty).
    baked : this bake's entries; they replace previous entries with the same (``blend``, ``name``).
    still_in_use : ``entry -> bool``, True for a previous entry whose light map is still used
        (its object exists and was not re-baked, or it belongs to another .blend).
    Previous entries keep their order, then the new ones follow.
    """
    replaced = {(e.get("blend", ""), e["name"]) for e in baked}
    kept = [e for e in previous if isinstance(e, dict) and "name" in e
            and (e.get("blend", ""), e["name"]) not in replaced and still_in_use(e)]
    return kept + list(baked)


def read_objects(path) -> list:
    """The ``objects`` of the manifest at ``path`` (folder or file), [] if there is none or it is unreadable."""
    try:
        return list(read_manifest(path).get("objects", []))
    except (OSError, ValueError, AttributeError):
        return []


def read_manifest(path) -> dict:
    """Read a manifest (folder or file path), checking ``schema_version``."""
    path = Path(path)
    if path.suffix.lower() != ".json":
        path = path / FILENAME
    with open(path, encoding="utf-8") as f:
        document = json.load(f)
    version = document.get("schema_version")
    if version != SCHEMA_VERSION:
        raise ValueError(f"{path}: schema_version {version!r}, this reader understands {SCHEMA_VERSION}")
    return document
