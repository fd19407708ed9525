"""Cache overlay: the last bake's irradiance records drawn in the 3D viewport (the paper's Figure 6).

Each record k = (p_k, n_k, E_k, R_k) is drawn as a point at p_k coloured by
its indirect irradiance E_k, and, on demand, as a disc of radius a*R_k (its
zone of influence, Equation 2) in the plane orthogonal to n_k: where discs
leave gaps the texels needed hole records (section 3.4).

Three layers, so everything but the GPU calls runs headless:

1. the records file (``pdic_records.npz``, written by :mod:`.job` next to the
   manifest): :func:`save_records` / :func:`load_records`, numpy only;
2. the batch builders :func:`point_arrays`, :func:`disc_arrays`,
   :func:`record_colours`: pure functions records -> vertex arrays (tested);
3. the draw handler: :func:`draw_records` turns those arrays into ``gpu``
   batches. It is registered on ``SpaceView3D`` for the whole session (one
   handler, checking ``scene.pdic.show_records`` each redraw, so toggling,
   undo and opening files need no bookkeeping) and returns at once in
   background mode, where the gpu module cannot draw.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

RECORDS_FILENAME = "pdic_records.npz"
"""Written next to ``pdic_manifest.json`` (or into the cache folder when images are packed)."""
DISC_SEGMENTS = 16
"""Triangles per disc; 16 keeps circles round at typical zoom (48 vertices per record)."""
DISC_ALPHA = 0.35
"""Disc opacity: overlapping zones show darker, coverage gaps stay see-through."""
SURFACE_LIFT = 1e-4
"""Points and discs are lifted off their surface by this fraction of the records' extent (no z-fighting)."""


# --------------------------------------------------------------------------- 1. the records file
@dataclass(frozen=True)
class RecordSet:
    """Irradiance records of one bake, struct of arrays (K records, 40 bytes each + origin).

    p_local : (K, 3) float32 scene-local positions p_k (world = p_local + origin_world).
    origin_world : (3,) float64 the bake's ``Scene.origin_world``.
    n : (K, 3) float32 unit normals n_k.
    E : (K, 3) float32 indirect irradiance E_k, W/m^2 (linear RGB).
    R : (K,) float32 harmonic mean distance R_k, scene units.
    a : float, Ward's accuracy the records were built with (zone radius a R_k).
    """

    p_local: np.ndarray
    origin_world: np.ndarray
    n: np.ndarray
    E: np.ndarray
    R: np.ndarray
    a: float

    def __post_init__(self):
        K = len(self.p_local)
        shapes = {"p_local": (K, 3), "n": (K, 3), "E": (K, 3), "R": (K,), "origin_world": (3,)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"records: {name} has shape {getattr(self, name).shape}, expected {shape}")

    def __len__(self) -> int:
        return len(self.p_local)

    @property
    def p_world(self) -> np.ndarray:
        """(K, 3) float64 world positions."""
        return self.p_local.astype(np.float64) + self.origin_world


def save_records(path, p_local, n, E, R, origin_world, a: float) -> Path:
    """Write the records of a bake to ``path`` (an ``.npz``), float32 except the origin.

    p_local, n, E : (K, 3) scene-local positions, unit normals, irradiance (W/m^2).
    R : (K,) harmonic mean distances (scene units). origin_world : (3,) float64.
    Raises ValueError naming the array if any value is NaN or infinite.
    """
    path = Path(path)
    arrays = dict(p_local=np.asarray(p_local, np.float32), n=np.asarray(n, np.float32),
                  E=np.asarray(E, np.float32), R=np.asarray(R, np.float32),
                  origin_world=np.asarray(origin_world, np.float64), a=np.float64(a))
    for name, value in arrays.items():
        if not np.isfinite(value).all():
            raise ValueError(f"records file {str(path)!r}: {name} has non-finite values")
    RecordSet(**{k: v for k, v in arrays.items() if k != "a"}, a=float(a))  # validates shapes
    with open(path, "wb") as f:  # a file object: numpy must not append another ".npz"
        np.savez_compressed(f, **arrays)
    return path


def load_records(path) -> RecordSet:
    """Read a records file written by :func:`save_records`; ValueError names the path if it is unusable."""
    path = Path(path)
    try:
        with np.load(path) as data:
            return RecordSet(p_local=data["p_local"].astype(np.float32), origin_world=data["origin_world"],
                             n=data["n"].astype(np.float32), E=data["E"].astype(np.float32),
                             R=data["R"].astype(np.float32), a=float(data["a"]))
    except (OSError, KeyError, ValueError) as e:
        raise ValueError(f"cannot read cache records {str(path)!r}: {e}") from e


# --------------------------------------------------------------------------- 2. batch builders (pure)
def record_colours(E: np.ndarray, alpha: float = 1.0, white: float | None = None) -> np.ndarray:
    """Display colours (K, 4) float32 in [0, 1] for irradiance E (K, 3).

    E is divided by ``white`` (default: the 99th percentile of the records'
    maximum channel, so a few hot records do not darken the rest), clipped to
    [0, 1] and gamma-encoded (1/2.2) for display; hue is kept. Zero
    irradiance is black. alpha : the fourth channel.
    """
    E = np.asarray(E, np.float64)
    if white is None:
        peak = E.max(axis=1) if len(E) else np.zeros(0)
        white = float(np.percentile(peak, 99)) if len(peak) else 1.0
    white = white if white > 0 and np.isfinite(white) else 1.0
    rgb = np.clip(E / white, 0.0, 1.0) ** (1.0 / 2.2)
    out = np.empty((len(E), 4), np.float32)
    out[:, :3] = rgb
    out[:, 3] = alpha
    return out


def _lift(records: RecordSet) -> np.ndarray:
    if len(records) == 0:
        return np.zeros(0)
    extent = float(np.linalg.norm(np.ptp(records.p_local, axis=0)))
    return SURFACE_LIFT * max(extent, 1e-6)


def point_arrays(records: RecordSet) -> tuple[np.ndarray, np.ndarray]:
    """Vertex arrays for a POINTS batch: positions (K, 3) float32 world, colours (K, 4) float32.

    Each point sits at p_k (world) lifted along n_k by :data:`SURFACE_LIFT` of the extent.
    """
    pos = records.p_world + _lift(records) * records.n.astype(np.float64)
    return np.ascontiguousarray(pos, np.float32), record_colours(records.E)


def tangent_frames(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents (t, b), each (K, 3) float64, for unit normals n (K, 3) (Duff et al. 2017)."""
    n = np.asarray(n, np.float64)
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    bt = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bt


def disc_arrays(records: RecordSet, segments: int = DISC_SEGMENTS, alpha: float = DISC_ALPHA
                ) -> tuple[np.ndarray, np.ndarray]:
    """Vertex arrays for a TRIS batch of zone-of-influence discs.

    Disc k: centre p_k (world, lifted like the points), radius a*R_k, in the
    plane orthogonal to n_k, as ``segments`` triangles (centre, rim i, rim i+1).

    Returns positions (K*segments*3, 3) float32 and colours (K*segments*3, 4)
    float32 (the record's colour with ``alpha``), triangles of a disc contiguous.
    """
    K = len(records)
    centre = records.p_world + _lift(records) * records.n.astype(np.float64)        # (K, 3)
    t, b = tangent_frames(records.n)
    radius = records.a * records.R.astype(np.float64)                                 # (K,)
    angle = 2.0 * np.pi * np.arange(segments + 1) / segments                          # (S+1,)
    rim = centre[:, None, :] + radius[:, None, None] * (
        np.cos(angle)[None, :, None] * t[:, None, :] + np.sin(angle)[None, :, None] * b[:, None, :])
    tris = np.empty((K, segments, 3, 3))
    tris[:, :, 0] = centre[:, None, :]
    tris[:, :, 1] = rim[:, :-1]
    tris[:, :, 2] = rim[:, 1:]
    colour = record_colours(records.E, alpha)
    colours = np.repeat(colour, segments * 3, axis=0)
    return np.ascontiguousarray(tris.reshape(-1, 3), np.float32), colours


# --------------------------------------------------------------------------- 3. drawing
def records_path(scene) -> Path | None:
    """Absolute path of the scene's last records file, or None if there is none."""
    props = getattr(scene, "pdic", None)
    if props is None or not props.records_file:
        return None
    return Path(bpy.path.abspath(props.records_file))


class OverlayState:
    """The draw handler's handle and its batches, keyed on what they depend on (file, mtime, mode)."""

    def __init__(self):
        self.handle = None
        self.key = None
        self.batches: list = []
        self.error: str = ""

    def clear(self):
        self.key, self.batches, self.error = None, [], ""


STATE = OverlayState()


def _batches(path: Path, discs: bool) -> list:
    """(shader, batch, is_points) triples for the records at ``path``; built once per file version and mode."""
    stat = path.stat()
    key = (str(path), stat.st_mtime_ns, stat.st_size, discs)
    if STATE.key == key:
        return STATE.batches
    import gpu
    from gpu_extras.batch import batch_for_shader

    records = load_records(path)
    batches = []
    if discs:
        pos, col = disc_arrays(records)
        shader = gpu.shader.from_builtin("FLAT_COLOR")
        batches.append((shader, batch_for_shader(shader, "TRIS", {"pos": pos, "color": col}), False))
    pos, col = point_arrays(records)
    shader = gpu.shader.from_builtin("POINT_FLAT_COLOR")
    batches.append((shader, batch_for_shader(shader, "POINTS", {"pos": pos, "color": col}), True))
    STATE.key, STATE.batches, STATE.error = key, batches, ""
    return batches


def draw_records():
    """SpaceView3D POST_VIEW callback: draw the records if the scene asks for them."""
    if bpy.app.background:  # no GPU drawing headless; never reached in practice
        return
    context = bpy.context
    props = getattr(context.scene, "pdic", None)
    space = context.space_data
    if props is None or not props.show_records or (space is not None and not space.overlay.show_overlays):
        return
    path = records_path(context.scene)
    if path is None or not path.is_file():
        return
    try:
        batches = _batches(path, props.show_record_discs)
    except (OSError, ValueError) as e:
        if STATE.error != str(e):  # say it once, not every redraw
            STATE.error = str(e)
            print(f"PDIC overlay: {e}")
        return
    import gpu

    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.blend_set("ALPHA")
    gpu.state.depth_mask_set(False)
    for shader, batch, is_points in batches:
        shader.bind()
        if is_points:  # POINT_FLAT_COLOR's uniform: point diameter in pixels
            shader.uniform_float("size", float(props.record_point_size))
        batch.draw(shader)
    gpu.state.depth_mask_set(True)
    gpu.state.blend_set("NONE")
    gpu.state.depth_test_set("NONE")


def tag_redraw(context=None):
    """Redraw every 3D viewport (after the overlay setting or the records changed)."""
    wm = getattr(context or bpy.context, "window_manager", None)
    for window in (wm.windows if wm is not None else ()):
        screen = window.screen
        for area in (screen.areas if screen is not None else ()):
            if area.type == "VIEW_3D":
                area.tag_redraw()


def register():
    # draw_handler_add only stores the callback (it works headless too); the callback
    # itself returns at once in background mode, where gpu cannot draw.
    if STATE.handle is None:
        STATE.handle = bpy.types.SpaceView3D.draw_handler_add(draw_records, (), "WINDOW", "POST_VIEW")


def unregister():
    if STATE.handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(STATE.handle, "WINDOW")
        STATE.handle = None
    STATE.clear()
