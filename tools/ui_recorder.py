"""A UILayout that records what a panel draws, checked against Blender's RNA (properties,
operators, icons). The UI tests assert on the recording, and docs/render_panel.py draws the
panel picture from it; both run on the bpy wheel, which has no window to draw into."""
from __future__ import annotations

from types import SimpleNamespace

from pdic.pdic_addon import preferences


def _enable_preferences(bpy):
    """What Blender does when it enables the add-on: an entry under the add-on's package name."""
    addon = bpy.context.preferences.addons.get(preferences.ROOT_PACKAGE)
    if addon is None:
        addon = bpy.context.preferences.addons.new()
        addon.module = preferences.ROOT_PACKAGE
    return addon.preferences


def _disable_preferences(bpy):
    addon = bpy.context.preferences.addons.get(preferences.ROOT_PACKAGE)
    if addon is not None:
        bpy.context.preferences.addons.remove(addon)


ICONS = None


def _icons():
    global ICONS
    if ICONS is None:
        import bpy
        ICONS = set(bpy.types.UILayout.bl_rna.functions["label"].parameters["icon"].enum_items.keys())
    return ICONS


class RecordedOperator:
    """What ``layout.operator()`` returns: assignments are checked against the operator's RNA."""

    def __init__(self, idname, rna):
        object.__setattr__(self, "idname", idname)
        object.__setattr__(self, "rna", rna)
        object.__setattr__(self, "values", {})

    def __setattr__(self, name, value):
        prop = self.rna.properties.get(name)
        assert prop is not None, f"{self.idname} has no property {name!r}"
        if prop.type == "ENUM":
            assert value in prop.enum_items.keys(), f"{self.idname}.{name}: {value!r} not in {prop.enum_items.keys()}"
        self.values[name] = value


class RecordingLayout:
    """Stands in for ``bpy.types.UILayout`` while a panel's draw function runs.

    A real UILayout exists only while Blender draws a region, which never
    happens in background mode (and ``window_manager.popup_menu`` crashes the
    bpy wheel headless: measured, segfault). This is not a mock of something
    that could run here: it records what the draw code asks for and checks
    every request against Blender's real RNA (property names on the real
    data, registered operators and their enum values, icon names).
    """

    def __init__(self, log=None, parent=None, kind="root", **options):
        self.log = log if log is not None else []
        self.parent, self.kind, self.options = parent, kind, options
        self.enabled = self.active = True
        self.use_property_split = self.use_property_decorate = False
        self.scale_y = 1.0

    # -- containers
    def _child(self, kind, **options):
        child = RecordingLayout(self.log, self, kind, **options)
        self.log.append(("layout", child, kind, options))
        return child

    def row(self, align=False, heading=""):
        return self._child("row", align=align, heading=heading)

    def column(self, align=False, heading=""):
        return self._child("column", align=align, heading=heading)

    def box(self):
        return self._child("box")

    def split(self, factor=0.0, align=False):
        return self._child("split", factor=factor)

    # -- items
    def prop(self, data, property, text=None, icon="NONE", toggle=False, expand=False, **_):
        rna = data.bl_rna.properties.get(property)
        assert rna is not None, f"{data.bl_rna.identifier} has no property {property!r}"
        assert icon in _icons(), icon
        self.log.append(("prop", self, data, property, rna.name if text is None else text, rna))

    def prop_search(self, data, property, search_data, search_property, text=None, icon="NONE", **_):
        """Recorded as a prop; the collection searched must exist on ``search_data``."""
        assert search_data.bl_rna.properties.get(search_property) is not None, \
            f"{search_data.bl_rna.identifier} has no collection {search_property!r}"
        self.prop(data, property, text=text, icon=icon)

    def operator(self, idname, text=None, icon="NONE", depress=False, **_):
        import bpy
        module, name = idname.split(".")
        rna = getattr(getattr(bpy.ops, module), name).get_rna_type()  # KeyError if not registered
        assert icon in _icons(), icon
        op = RecordedOperator(idname, rna)
        self.log.append(("operator", self, idname, rna.name if text is None else text, op, depress))
        return op

    def label(self, text="", icon="NONE"):
        assert icon in _icons(), icon
        self.log.append(("label", self, text, icon))

    def separator(self, factor=1.0):
        self.log.append(("separator", self))

    def progress(self, factor=0.0, text="", type="BAR"):
        assert 0.0 <= factor <= 1.0
        self.log.append(("progress", self, factor, text))

    # -- queries for the tests
    def is_active(self) -> bool:
        node = self
        while node is not None:
            if not (node.active and node.enabled):
                return False
            node = node.parent
        return True

    def props(self):
        return [e[3] for e in self.log if e[0] == "prop"]

    def labels(self):
        return [e[2] for e in self.log if e[0] == "label"]

    def operators(self):
        return [(e[2], e[4].values, e[5]) for e in self.log if e[0] == "operator"]


def draw_panel(panel_cls, context):
    """Run ``panel_cls.draw`` on a recording layout (the Panel's draw function, unchanged)."""
    layout = RecordingLayout()
    panel_cls.draw(SimpleNamespace(layout=layout), context)
    return layout
