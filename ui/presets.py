"""Setting presets (Add/Remove through AddPresetBase) and the shipped defaults.

The shipped presets in ``preset_files/`` are copied into the user's preset
folder (``scripts/presets/furcollide``) on register, without overwriting a
file the user already has.
"""

import os
import shutil

import bpy
from bl_operators.presets import AddPresetBase
from bl_ui.utils import PresetPanel
from bpy.types import Menu, Operator, Panel

from ..operators.ops.common import SetupOperator
from ..operators.settings.properties import SOLVER_PROPERTIES

PRESET_SUBDIR = "furcollide"
SHIPPED_DIR = os.path.join(os.path.dirname(__file__), "preset_files")


class FURCOLLIDE_MT_presets(Menu):
    """FurCollide setting presets."""

    bl_label = "FurCollide Presets"
    preset_subdir = PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    draw = Menu.draw_preset


class FURCOLLIDE_PT_presets(PresetPanel, Panel):
    bl_label = "FurCollide Presets"
    preset_subdir = PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    preset_add_operator = "furcollide.preset_add"


class FURCOLLIDE_OT_preset_add(AddPresetBase, SetupOperator, Operator):
    """Add or remove a FurCollide preset from the current solver settings"""

    bl_idname = "furcollide.preset_add"
    bl_label = "Add FurCollide Preset"
    preset_menu = "FURCOLLIDE_MT_presets"
    preset_subdir = PRESET_SUBDIR
    preset_defines = [
        "fc = bpy.context.object.furcollide",
        "settings = fc.source.furcollide if fc.is_output and fc.source else fc",
    ]
    preset_values = [f"settings.{name}" for name in SOLVER_PROPERTIES]


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


classes = (FURCOLLIDE_MT_presets, FURCOLLIDE_PT_presets, FURCOLLIDE_OT_preset_add)
