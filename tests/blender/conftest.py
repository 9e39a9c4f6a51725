"""Blender-side test set-up (real ``bpy`` wheel, no mocks).

* ``BLENDER_USER_RESOURCES`` points to a temporary folder *before* ``bpy`` is
  imported, so no installed extension (or its wheels) can shadow the venv.
* The repository is registered as an extension from a temporary "dev"
  repository whose folder contains a symlink ``furcollide -> <repo root>``
  (CI may clone the repository under another name).
* Every test starts from an empty factory scene (``read_homefile``), which
  keeps the add-on enabled.
"""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
import types
from pathlib import Path

import pytest

_USER = tempfile.mkdtemp(prefix="furcollide_user_")
os.environ["BLENDER_USER_RESOURCES"] = _USER

bpy = pytest.importorskip("bpy")
import addon_utils  # noqa: E402  (needs bpy first)
import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
DEV_DIR = Path(tempfile.mkdtemp(prefix="furcollide_dev_"))
(DEV_DIR / "furcollide").symlink_to(REPO, target_is_directory=True)
ADDON = "bl_ext.fcdev.furcollide"


@atexit.register
def _cleanup():
    link = DEV_DIR / "furcollide"
    if link.is_symlink():
        link.unlink()  # the link only, never the repository behind it
    shutil.rmtree(DEV_DIR, ignore_errors=True)
    shutil.rmtree(_USER, ignore_errors=True)


@pytest.fixture(scope="module", autouse=True)
def furcollide_addon():
    """Enable the add-on from the dev repository for each test module (and disable it
    afterwards, so register/unregister run repeatedly and nothing leaks into other
    test directories)."""
    repos = bpy.context.preferences.extensions.repos
    if "fcdev" not in {r.module for r in repos}:
        repos.new(name="fcdev", module="fcdev", custom_directory=str(DEV_DIR), source="USER")
    mod = addon_utils.enable(ADDON, default_set=True, handle_error=None)
    assert mod is not None, "FurCollide add-on failed to enable"
    yield mod
    addon_utils.disable(ADDON, default_set=True)


@pytest.fixture(autouse=True)
def clean_scene(furcollide_addon):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    yield


#: The add-on's modules the tests reach (``fc.<name>``), in ``operators`` unless named.
_MODULES = ("bake", "bridge", "cli", "colliders", "dependencies", "frame_inputs",
            "frame_outputs", "frame_rules", "frame_solve", "fur_attach", "groom_stage",
            "invalidation", "motion", "properties", "property_helpers", "registry")


@pytest.fixture
def fc():
    """The add-on's modules (``fc.registry``, ``fc.frame_rules``, ``fc.cache`` (the core's
    frame cache) ...), ``fc.Setup`` and scene helpers."""
    pkg = ADDON
    ns = types.SimpleNamespace(
        cache=sys.modules[pkg + ".core.framecache"],
        core=sys.modules[pkg + ".core"],
        package=sys.modules[pkg],
        Setup=sys.modules[pkg + ".operators.setup"].Setup,
        setup_module=sys.modules[pkg + ".operators.setup"],
        make_scene=make_scene,
        positions=positions,
        setup=setup,
        **{name: sys.modules[f"{pkg}.operators.{name}"] for name in _MODULES},
    )
    return ns


# ------------------------------------------------------------------ helpers
def make_hair(name="Fur", nx=6, ny=6, npts=5, length=1.0, spacing=0.2):
    """A grid of straight vertical hairs on z = 0 (nx * ny curves)."""
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([npts] * (nx * ny))
    xs = (np.arange(nx) - (nx - 1) / 2) * spacing
    ys = (np.arange(ny) - (ny - 1) / 2) * spacing
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(nx * ny)], 1)
    t = np.linspace(0, length, npts)
    P = (roots[:, None, :] + t[None, :, None] * np.array([0, 0, 1.0])).reshape(-1, 3)
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def make_surface(name="Skin", half=1.0, n=8, z=0.0, uv=True):
    """A subdivided square (n x n quads) on z, as a growth surface; ``uv``: with a
    UV map named UVMap (Fur Attach needs none)."""
    xs = np.linspace(-half, half, n + 1)
    verts = [(x, y, z) for y in xs for x in xs]
    faces = [
        (j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
        for j in range(n) for i in range(n)
    ]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    if uv:
        me.uv_layers.new(name="UVMap")
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def make_box(name="Box", size=0.5, location=(0, 0, 0.6)):
    """A closed cube mesh object (12 triangles) of edge ``size``."""
    h = size / 2
    verts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    faces = [
        (0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1),
        (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3),
    ]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    ob.location = location
    return ob


def make_scene(frames=(1, 12), nx=6, ny=6, animate=True):
    """Hair grid + a box sweeping through it along x over ``frames``."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    hair = make_hair(nx=nx, ny=ny)
    box = make_box()
    if animate:
        box.location = (-1.2, 0, 0.6)
        box.keyframe_insert("location", frame=frames[0])
        box.location = (1.2, 0, 0.6)
        box.keyframe_insert("location", frame=frames[1])
        for fc_ in box.animation_data.action.fcurves if hasattr(
            box.animation_data.action, "fcurves"
        ) else []:
            for k in fc_.keyframe_points:
                k.interpolation = "LINEAR"
    scene.frame_set(frames[0])
    return hair, box


def activate(ob, *selected):
    """Make ``ob`` the active object, with ``selected`` (and ``ob``) selected."""
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in selected:
        o.select_set(True)
    ob.select_set(True)
    bpy.context.view_layer.objects.active = ob


def setup(hair, colliders):
    """Run furcollide.add with ``hair`` active and ``colliders`` selected."""
    activate(hair, *colliders)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    return hair.furcollide.output


def render_camera(scene, engine="BLENDER_WORKBENCH", px=32):
    """A small, fast render set-up: an orthographic camera looking at the
    origin from -Y, ``px`` x ``px`` pixels, Lock Interface on."""
    import numpy as np

    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 3.0
    cam.location = (0, -5, 0.5)
    cam.rotation_euler = (np.pi / 2, 0, 0)
    scene.render.engine = engine
    if engine == "CYCLES":
        scene.cycles.samples = 1
        scene.cycles.device = "CPU"
    scene.render.resolution_x = scene.render.resolution_y = px
    scene.render.use_lock_interface = True
    return cam


def positions(ob):
    """Original point positions of a hair object, (P, 3) float32."""
    d = ob.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


def bake_crashing_at(fc, monkeypatch, frame, match="simulated crash"):
    """Run furcollide.bake with a simulated crash in ``frame`` (the frames before
    it are kept on disk); the error message must match ``match``."""
    import pytest

    real = fc.bake.bake_frame

    def crashing(setup, directory, trust_solver):
        if setup.frame == frame:
            raise RuntimeError("simulated crash")
        return real(setup, directory, trust_solver)

    with monkeypatch.context() as m:
        m.setattr(fc.bake, "bake_frame", crashing)
        with pytest.raises(RuntimeError, match=match):
            bpy.ops.furcollide.bake()
