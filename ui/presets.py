"""Setting presets: Add/Remove (AddPresetBase), applying one, and the shipped defaults.

A preset is a small Python file in the user's preset folder (``scripts/presets/
furcollide``) that sets the solver settings of the active setup. This version writes
(:meth:`FURCOLLIDE_OT_preset_add.add`)::

    furcollide_settings_version = 1
    settings.mode = 'BEND'
    settings.max_angle = math.radians(180.0)

Presets written by earlier versions have no ``furcollide_settings_version`` line: their
angles are plain degrees (``settings.max_angle = 180.0``) and their choices lower case
(``settings.mode = 'bend'``). Applying a preset (:class:`FURCOLLIDE_OT_preset_apply`, what
the preset menu calls) reads such a file as it was meant (:func:`upgraded`): the angles
through ``math.radians``, the choices upper case. The file itself is never changed.

The shipped presets in ``preset_files/`` are copied into the user's preset folder on
register, without overwriting a file the user already has.
"""

from __future__ import annotations

import ast
import math
import os
import shutil

import bpy
import numpy as np
from bl_operators.presets import AddPresetBase
from bl_ui.utils import PresetPanel
from bpy.props import StringProperty
from bpy.types import Menu, Operator, Panel

from ..operators.ops.common import SetupOperator
from ..operators.settings import angles
from ..operators.settings.core_values import CORE_CHOICES
from ..operators.settings.properties import CURRENT_VERSION, SOLVER_PROPERTIES

PRESET_SUBDIR = "furcollide"
SHIPPED_DIR = os.path.join(os.path.dirname(__file__), "preset_files")
#: The line that says which version wrote a preset (absent: an earlier version's).
VERSION_NAME = "furcollide_settings_version"
#: What a preset file runs first: the setup the active object belongs to.
DEFINES = (
    "fc = bpy.context.object.furcollide",
    "settings = fc.source.furcollide if fc.is_output and fc.source else fc",
)


class FURCOLLIDE_MT_presets(Menu):
    """FurCollide setting presets."""

    bl_label = "FurCollide Presets"
    preset_subdir = PRESET_SUBDIR
    preset_operator = "furcollide.preset_apply"
    draw = Menu.draw_preset


class FURCOLLIDE_PT_presets(PresetPanel, Panel):
    bl_label = "FurCollide Presets"
    preset_subdir = PRESET_SUBDIR
    preset_operator = "furcollide.preset_apply"
    preset_add_operator = "furcollide.preset_add"


def _literal(value) -> str:
    """``value`` as Python source: a float32 setting by its shortest decimal form."""
    if isinstance(value, float) and math.isfinite(value):
        return str(np.float32(value))
    if isinstance(value, float):
        return f"float({str(value)!r})"
    return repr(value)


def preset_source(s) -> str:
    """The preset file of the solver settings of setup properties ``s``."""
    lines = ["import math", "", "import bpy", "", *DEFINES, f"{VERSION_NAME} = {CURRENT_VERSION}",
             ""]
    for name in SOLVER_PROPERTIES:
        if name in angles.ANGLES:  # (degrees, as stored: exact once back in radians)
            lines.append(f"settings.{name} = math.radians({_literal(angles.degrees(s, name))})")
        else:
            lines.append(f"settings.{name} = {_literal(getattr(s, name))}")
    return "\n".join(lines) + "\n"


class FURCOLLIDE_OT_preset_add(AddPresetBase, SetupOperator, Operator):
    """Add or remove a FurCollide preset from the current solver settings"""

    bl_idname = "furcollide.preset_add"
    bl_label = "Add FurCollide Preset"
    preset_menu = "FURCOLLIDE_MT_presets"
    preset_subdir = PRESET_SUBDIR
    preset_defines = list(DEFINES)
    preset_values = [f"settings.{name}" for name in SOLVER_PROPERTIES]

    def add(self, context, filepath):
        """Write the preset (AddPresetBase calls this instead of writing its own)."""
        fc = context.object.furcollide
        s = fc.source.furcollide if fc.is_output and fc.source else fc
        with open(filepath, "w", encoding="utf-8") as fh:
            fh.write(preset_source(s))


def preset_version(tree) -> int:
    """The ``furcollide_settings_version`` a preset's syntax ``tree`` sets (0: none, an
    earlier version's preset)."""
    for node in tree.body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1
                and isinstance(node.targets[0], ast.Name)
                and node.targets[0].id == VERSION_NAME
                and isinstance(node.value, ast.Constant)):
            return int(node.value.value)
    return 0


class _Upgrade(ast.NodeTransformer):
    """An earlier version's preset read as meant: ``settings.<angle> = x`` becomes
    ``settings.<angle> = _radians(x)``, ``settings.<choice> = x`` becomes
    ``settings.<choice> = _choice(x)``."""

    def visit_Assign(self, node):
        for target in node.targets:
            if (isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name)
                    and target.value.id == "settings"):
                wrap = ("_radians" if target.attr in angles.ANGLES else
                        "_choice" if target.attr in CORE_CHOICES else None)
                if wrap:
                    node.value = ast.copy_location(ast.Call(
                        ast.Name(wrap, ast.Load()), [node.value], []), node.value)
        return node


def upgraded(source, filename="<preset>"):
    """The code object of preset ``source``, an earlier version's read as it was meant
    (raises SyntaxError as Python would)."""
    tree = ast.parse(source, filename)
    if preset_version(tree) < 1:
        tree = ast.fix_missing_locations(_Upgrade().visit(tree))
    return compile(tree, filename, "exec")


def _choice(value):
    return value.upper() if isinstance(value, str) else value


class FURCOLLIDE_OT_preset_apply(SetupOperator, Operator):
    """Apply a FurCollide preset to the active setup's solver settings (a preset saved
    by an earlier version too: its angles in degrees and its choices are read as they
    were meant)"""

    bl_idname = "furcollide.preset_apply"
    bl_label = "Apply FurCollide Preset"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(
        name="File Path", subtype="FILE_PATH", options={"SKIP_SAVE"},
        description="The preset file to apply (a Python file)",
    )
    menu_idname: StringProperty(
        name="Menu ID Name", options={"SKIP_SAVE"},
        description="The preset menu or panel this was chosen from (it shows the name)",
    )

    @classmethod
    def refusal(cls, context, src):
        return ("The setup is baked: Free Bake first (its settings are the bake's)"
                if src.furcollide.is_baked else "")

    def execute(self, context):
        menu = getattr(bpy.types, self.menu_idname, None)
        if menu is not None:  # (the menu shows the preset chosen last, as Blender's do)
            menu.bl_label = bpy.path.display_name(os.path.basename(self.filepath),
                                                  title_case=False)
        try:
            with open(self.filepath, encoding="utf-8") as fh:
                code = upgraded(fh.read(), self.filepath)
            exec(code, {"__name__": "__main__", "__file__": self.filepath,  # noqa: S102
                        "_radians": math.radians, "_choice": _choice})
        except Exception as ex:  # noqa: BLE001 - reported, as Blender reports a preset's
            self.report({"ERROR"}, f"Failed to execute the preset: {ex!r}")
        return {"FINISHED"}


def install_shipped_presets() -> list[str]:
    """Copy the shipped presets into the user preset folder; returns new paths."""
    try:
        target = bpy.utils.user_resource("SCRIPTS", path=os.path.join("presets", PRESET_SUBDIR),
                                         create=True)
    except (OSError, ValueError) as exc:
        print(f"FurCollide: presets not installed: {exc}")
        return []
    if not target or not os.path.isdir(SHIPPED_DIR):
        return []
    new = []
    for name in sorted(os.listdir(SHIPPED_DIR)):
        if not name.endswith(".py"):
            continue
        dst = os.path.join(target, name)
        if not os.path.exists(dst):
            try:
                shutil.copyfile(os.path.join(SHIPPED_DIR, name), dst)
                new.append(dst)
            except OSError as exc:
                print(f"FurCollide: preset {name} not installed: {exc}")
    return new


classes = (FURCOLLIDE_MT_presets, FURCOLLIDE_PT_presets, FURCOLLIDE_OT_preset_add,
           FURCOLLIDE_OT_preset_apply)
