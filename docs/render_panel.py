"""Render docs/panel.png: a picture of the "Lightmaps" sidebar tab, made headless.

Blender cannot draw its UI in background mode (no GPU context; a popup
crashes the bpy wheel), so a real screenshot cannot be taken here. This
script runs the panels' own draw functions against the recording layout of
tools/ui_recorder.py (which checks every property, operator and icon against
Blender's RNA; the UI tests use it too), then lays the recorded rows out in Blender's dark-theme
colours: numpy for the boxes, Blender's own font renderer (``blf``
drawing into an ``imbuf``) for the text. Icons are left out; sizes follow
Blender's 20 px widget unit.

Run from the repository root::

    .venv/bin/python docs/render_panel.py [out.png]
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()

import bpy  # noqa: E402  (first: it makes blf and imbuf importable)
import blf  # noqa: E402
import imbuf  # noqa: E402
import numpy as np  # noqa: E402

from pdic import pdic_addon  # noqa: E402
from pdic.pdic_addon import panels  # noqa: E402
from tools.ui_recorder import RecordingLayout, _enable_preferences  # noqa: E402

# Blender's default dark theme (approximately), linear 0..1 sRGB values written as-is to a PNG.
BACKGROUND = (0.188, 0.188, 0.188)
PANEL = (0.24, 0.24, 0.24)
HEADER = (0.26, 0.26, 0.26)
SUBHEADER = (0.22, 0.22, 0.22)
BUTTON = (0.33, 0.33, 0.33)
NUMBER = (0.33, 0.33, 0.33)
TEXT_FIELD = (0.114, 0.114, 0.114)
SELECTED = (0.278, 0.447, 0.702)
TEXT = (0.9, 0.9, 0.9)

WIDTH = 340
UNIT = 22          # widget height
GAP = 2            # between aligned widgets
SPACE = 5          # between unaligned widgets
MARGIN = 10
FONT_SIZE = 11.5


class Canvas:
    """Rectangles in numpy (top-left origin), text queued for blf."""

    def __init__(self, width, height):
        self.w, self.h = width, height
        self.px = np.empty((height, width, 4), np.float32)
        self.px[...] = (*BACKGROUND, 1.0)
        self.texts = []

    def rect(self, x, y, w, h, colour):
        x0, y0 = max(int(x), 0), max(int(y), 0)
        self.px[y0:int(y + h), x0:int(x + w), :3] = colour

    def triangle_down(self, x, y, size, colour):
        for i in range(size):
            self.rect(x + i // 2, y + i // 2, size - (i // 2) * 2, 1, colour)

    def text(self, x, y, s, colour=TEXT, align="left", width=0, dim=False):
        self.texts.append((x, y, s, colour, align, width, dim))

    def save(self, path):
        tmp = Path(tempfile.mkdtemp()) / "boxes.png"
        image = bpy.data.images.new("pdic_panel", self.w, self.h, alpha=False)
        image.pixels.foreach_set(self.px[::-1].ravel())  # Blender rows go bottom-up
        image.filepath_raw, image.file_format = str(tmp), "PNG"
        image.save()
        buf = imbuf.load(str(tmp))
        with blf.bind_imbuf(0, buf):
            blf.size(0, FONT_SIZE)
            for x, y, s, colour, align, width, dim in self.texts:
                tw, th = blf.dimensions(0, s)
                if align == "center":
                    x += (width - tw) / 2
                elif align == "right":
                    x += width - tw
                blf.color(0, *colour, 0.5 if dim else 1.0)
                blf.position(0, x, self.h - y - (UNIT + 8) / 2, 0)  # baseline of a widget row
                blf.draw_buffer(0, s)
        imbuf.write(buf, filepath=str(path))


# --------------------------------------------------------------------------- the recorded tree
def children_of(log):
    kids = {}
    for e in log:
        node = e[1].parent if e[0] == "layout" else e[1]
        kids.setdefault(id(node), []).append(e)
    return kids


def split_mode(node):
    while node is not None:
        if node.use_property_split:
            return True
        node = node.parent
    return False


def value_text(data, prop, rna):
    value = getattr(data, prop)
    if rna.type == "ENUM":
        return rna.enum_items[value].name
    if rna.type == "FLOAT":
        return f"{value:.0f} px" if rna.subtype == "PIXEL" else f"{value:.{max(rna.precision, 2)}f}"
    if rna.type == "INT":
        return f"{value:,}" if value >= 10_000 else str(value)
    return str(value)


class Painter:
    def __init__(self, canvas, kids):
        self.c, self.kids = canvas, kids

    def node(self, node, x, y, w, dry=False) -> int:
        """Lay out ``node``'s items from (x, y) in width w; returns the height used."""
        items = self.kids.get(id(node), [])
        if node.kind == "row" or node.kind == "split":
            return self.horizontal(node, items, x, y, w, dry)
        top = y
        align = node.options.get("align", False)
        heading = node.options.get("heading", "")
        if heading and split_mode(node) and not dry:
            self.c.text(x, y, heading, align="right", width=w * 0.4 - 8)
        for item in items:
            y += self.item(item, x, y, w, dry) + (GAP if align else SPACE)
        return max(y - top - (GAP if align else SPACE), 0)

    def horizontal(self, node, items, x, y, w, dry):
        heading = node.options.get("heading", "")
        if heading and split_mode(node):
            if not dry:
                self.c.text(x, y, heading, align="right", width=w * 0.4 - 8)
            x, w = x + w * 0.4, w * 0.6
        if node.kind == "split":
            f = node.options.get("factor", 0.5) or 0.5
            widths = [w * f, w * (1 - f)]
        else:
            widths = [w / max(len(items), 1)] * len(items)
        h = 0
        for item, iw in zip(items, widths):
            h = max(h, self.item(item, x, y, iw - (0 if node.options.get("align") else 2), dry))
            x += iw
        return h

    def item(self, e, x, y, w, dry=False) -> int:
        kind = e[0]
        if kind == "layout":
            return self.node(e[1], x, y, w, dry)
        if kind == "separator":
            return 6
        if dry:
            return UNIT
        node = e[1]
        dim = not node.is_active()
        c = self.c
        if kind == "label":
            c.text(x + 4, y, e[2], dim=dim)
        elif kind == "operator":
            scale = getattr(node, "scale_y", 1.0)
            c.rect(x, y, w, UNIT * scale, SELECTED if e[5] else BUTTON)
            c.text(x, y + (UNIT * scale - UNIT) / 2, e[3], align="center", width=w, dim=dim)
            return int(UNIT * scale)
        elif kind == "progress":
            c.rect(x, y, w, UNIT, TEXT_FIELD)
            c.rect(x, y, w * e[2], UNIT, SELECTED)
            c.text(x, y, e[3], align="center", width=w)
        elif kind == "prop":
            self.prop(e, x, y, w, dim)
        return UNIT

    def prop(self, e, x, y, w, dim):
        _, node, data, prop, text, rna = e
        c = self.c
        split = split_mode(node) and not (rna.type == "ENUM" and getattr(rna, "is_enum_flag", False))
        if rna.type == "ENUM" and node.kind == "row" and len(self.kids.get(id(node), [])) == 1:
            items = list(rna.enum_items)  # expanded enum: segmented buttons
            seg = w / len(items)
            for i, item in enumerate(items):
                c.rect(x + i * seg, y, seg - 1, UNIT, SELECTED if item.identifier == getattr(data, prop) else BUTTON)
                c.text(x + i * seg, y, item.name, align="center", width=seg, dim=dim)
            return
        if rna.type == "BOOLEAN":
            value = getattr(data, prop)
            if node.kind == "row" and node.options.get("heading"):  # toggle buttons
                c.rect(x, y, w, UNIT, SELECTED if value else BUTTON)
                c.text(x, y, text, align="center", width=w, dim=dim)
                return
            bx = x + (w * 0.4 if split else 0)
            c.rect(bx + 2, y + 4, UNIT - 8, UNIT - 8, SELECTED if value else BUTTON)
            if value:
                c.rect(bx + 6, y + 8, UNIT - 16, UNIT - 16, TEXT)
            c.text(bx + UNIT, y, text, dim=dim)
            return
        fx, fw = (x + w * 0.4, w * 0.6) if split else (x, w)
        if split:
            c.text(x, y, text, align="right", width=w * 0.4 - 8, dim=dim)
        value = value_text(data, prop, rna)
        if rna.type == "STRING":
            c.rect(fx, y, fw, UNIT, TEXT_FIELD)
            c.text(fx + 6, y, value, dim=dim)
        elif rna.type == "ENUM":
            c.rect(fx, y, fw, UNIT, BUTTON)
            c.text(fx + 6, y, value, dim=dim)
        else:
            c.rect(fx, y, fw, UNIT, NUMBER)
            if split:
                c.text(fx, y, value, align="center", width=fw, dim=dim)
            else:
                c.text(fx + 6, y, text, dim=dim)
                c.text(fx, y, value, align="right", width=fw - 6, dim=dim)


# --------------------------------------------------------------------------- the panels
def record(panel_cls, context):
    layout = RecordingLayout()
    panel_cls.draw(SimpleNamespace(layout=layout), context)
    return layout


def render(path: Path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    pdic_addon.register()
    _enable_preferences(bpy)
    # The Cornell box with an area light, Final quality at 64x64 texels per object (~30 s on 2 cores).
    work = Path(tempfile.mkdtemp())
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "cornell_area.blend"))
    bpy.ops.wm.save_as_mainfile(filepath=str(work / "cornell_area.blend"))
    props = bpy.context.scene.pdic
    props.quality, props.default_resolution, props.texel_density = "FINAL", 64, 0.0
    props.output_folder = "//pdic_lightmaps/"
    assert bpy.ops.pdic.bake() == {"FINISHED"}
    props.show_records = True
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    bpy.context.view_layer.objects.active = meshes[0]
    sections = [("PDIC Light Maps", panels.VIEW3D_PT_pdic)] + [
        (cls.bl_label, cls) for cls in panels.classes if getattr(cls, "bl_parent_id", "") == "VIEW3D_PT_pdic"]
    recorded = [(title, record(cls, bpy.context)) for title, cls in sections]

    def paint(canvas, dry):
        y = 8
        for i, (title, layout) in enumerate(recorded):
            sub = i > 0
            x0, w0 = (MARGIN + 4, WIDTH - 2 * MARGIN - 8) if sub else (MARGIN - 4, WIDTH - 2 * MARGIN + 8)
            if not dry:
                canvas.rect(x0, y, w0, UNIT + 4, SUBHEADER if sub else HEADER)
                canvas.triangle_down(x0 + 8, y + 10, 8, TEXT)
                canvas.text(x0 + 22, y + 2, title)
            y += UNIT + 4
            painter = Painter(canvas, children_of(layout.log))
            h = painter.node(layout, x0 + 8, y + 6, w0 - 16, dry=True)
            if not dry:
                canvas.rect(x0, y, w0, h + 12, PANEL)
                painter.node(layout, x0 + 8, y + 6, w0 - 16)
            y += h + 12 + (2 if sub else 4)
        return y + 6

    height = paint(Canvas(WIDTH, 10), dry=True)
    canvas = Canvas(WIDTH, int(height))
    canvas.rect(MARGIN - 4, 8, WIDTH - 2 * MARGIN + 8, height - 14, PANEL)
    paint(canvas, dry=False)
    canvas.save(path)
    pdic_addon.unregister()
    return path


if __name__ == "__main__":
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "panel.png"
    print(render(out))
