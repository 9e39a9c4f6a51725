"""Install a built FurCollide zip into a fresh, isolated Blender and drive it.

Run in a *subprocess* by ``test_install.py``::

    python _install_check.py <zip> <workdir>          # install, enable, drive
    python _install_check.py --next-session <workdir> # a later Blender session
    python _install_check.py --no-embree <zip> <workdir>  # embreex cannot load here

``BLENDER_USER_RESOURCES`` must point at an empty temporary folder (set by the
caller before this interpreter starts, so ``bpy`` sees it at import). The
last line of stdout is one JSON object with what was found; the test asserts
on it. Nothing here imports the repository checkout: only the installed copy.
"""

import importlib
import json
import os
import sys
import traceback

ADDON = "bl_ext.user_default.furcollide"


def cube(center, half):
    import numpy as np

    c = np.asarray(center, np.float32)
    V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    V = V * half + c
    # Outward-wound quads of the cube (vertex index = 4x + 2y + z with 0/1 bits).
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    F = []
    for a, b, c2, d in quads:
        F += [(a, b, c2), (a, c2, d)]
    return V, np.array(F, np.int32)


def curve_points(n_cv=8, length=2.0, xs=(0.0, 3.0)):
    """Straight vertical curves at x in ``xs``; the first one crosses the cube."""
    import numpy as np

    z = np.linspace(0.0, length, n_cv, dtype=np.float32)
    pts = [np.stack([np.full(n_cv, x, np.float32), np.zeros(n_cv, np.float32), z], 1) for x in xs]
    return np.concatenate(pts).astype(np.float32)


def check_core(out, pkg):
    import numpy as np

    core = importlib.import_module(pkg + ".core")
    out["core_file"] = core.__file__
    names = ("Collider", "Settings", "Solver")
    out["core_has_solver_api"] = all(hasattr(core, n) for n in names)
    if not out["core_has_solver_api"]:
        out["core_missing"] = [n for n in names if not hasattr(core, n)]
        return
    V, F = cube((0.0, 0.0, 1.0), 0.5)
    col = core.Collider(V, F, double_sided=False, matrix=np.eye(4))
    P = curve_points()
    offsets = np.array([0, 8, 16], np.int64)
    solver = core.Solver(offsets, core.Settings(mode="bend"))
    res = solver.step(P, [col])
    moved = np.abs(np.asarray(res.points) - P).max(axis=1)
    out["core_step"] = {
        "finite": bool(np.isfinite(res.points).all()),
        "shape_ok": tuple(np.shape(res.points)) == P.shape,
        "status": [int(s) for s in np.asarray(res.status)],
        "moved_curve0": float(moved[:8].max()),
        "moved_curve1": float(moved[8:].max()),
    }


def check_operators(out, workdir):
    import bpy
    import numpy as np

    ops = sorted(dir(bpy.ops.furcollide))
    out["operators"] = ops
    if "add" not in ops:
        return
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    V, F = cube((0.0, 0.0, 1.0), 0.5)
    me = bpy.data.meshes.new("Box")
    me.from_pydata(V.tolist(), [], F.tolist())
    me.update()
    box = bpy.data.objects.new("Box", me)
    scene.collection.objects.link(box)
    hc = bpy.data.hair_curves.new("Fur")
    hc.add_curves([8, 8])
    P = curve_points()
    hc.position_data.foreach_set("vector", P.ravel())
    hc.update_tag()
    fur = bpy.data.objects.new("Fur", hc)
    scene.collection.objects.link(fur)
    for ob in scene.objects:
        ob.select_set(False)
    box.select_set(True)
    fur.select_set(True)
    bpy.context.view_layer.objects.active = fur
    before = {o.name for o in bpy.data.objects}
    out["op_add"] = sorted(bpy.ops.furcollide.add())
    out["new_objects"] = sorted({o.name for o in bpy.data.objects} - before)
    blend = os.path.join(workdir, "installed.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    if "bake_all" in ops:
        out["op_bake_all"] = sorted(bpy.ops.furcollide.bake_all())
    scene.frame_set(2)
    # The output is the one hair object FurCollide made (never the source).
    outputs = [o for o in scene.objects if o.type == "CURVES" and o.name != "Fur"]
    out["output_objects"] = [o.name for o in outputs]
    src_after = np.empty(len(hc.points) * 3, np.float32)
    hc.position_data.foreach_get("vector", src_after)
    out["source_untouched"] = bool(np.array_equal(src_after, P.ravel()))
    if outputs:
        oc = outputs[0].data
        Q = np.empty(len(oc.points) * 3, np.float32)
        oc.position_data.foreach_get("vector", Q)
        Q = Q.reshape(-1, 3)
        if Q.shape == P.shape:
            moved = np.abs(Q - P).max(axis=1)
            out["op_moved_curve0"] = float(moved[:8].max())
            out["op_moved_curve1"] = float(moved[8:].max())


def next_session(out):
    """A later session: files are on disk, the add-on must be enabled again."""
    import bpy  # noqa: I001  (bpy first: it makes addon_utils importable)
    import addon_utils

    out["enabled_at_start"] = ADDON in bpy.context.preferences.addons
    mod = addon_utils.enable(ADDON, default_set=True, handle_error=None)
    out["enabled"] = mod is not None and ADDON in bpy.context.preferences.addons
    out["module_file"] = getattr(mod, "__file__", None)
    import embreex

    out["embreex_file"] = embreex.__file__


class _BlockEmbreex:
    """Meta-path finder that makes ``import embreex`` fail (a platform without it)."""

    def find_spec(self, name, path=None, target=None):
        if name == "embreex" or name.startswith("embreex."):
            raise ImportError("embreex is blocked by the test (simulated unsupported platform)")
        return None


def check_no_embree(out):
    """The add-on must still enable and explain itself instead of failing obscurely."""
    import bpy

    pkg = importlib.import_module(ADDON + ".core")
    out["embree_available"] = bool(pkg.embree_available())
    out["embree_error"] = pkg.embree_error()
    hc = bpy.data.hair_curves.new("Fur")
    hc.add_curves([4])
    fur = bpy.data.objects.new("Fur", hc)
    bpy.context.scene.collection.objects.link(fur)
    bpy.context.view_layer.objects.active = fur
    fur.select_set(True)
    try:
        out["op_add"] = sorted(bpy.ops.furcollide.add())
    except RuntimeError as err:
        out["op_add_error"] = str(err)


def main():
    out = {"user_resources": os.environ.get("BLENDER_USER_RESOURCES")}
    no_embree = sys.argv[1] == "--no-embree"
    if no_embree:
        sys.argv.pop(1)
        sys.meta_path.insert(0, _BlockEmbreex())
    if sys.argv[1] == "--next-session":
        try:
            next_session(out)
        except Exception:
            out.setdefault("errors", []).append(traceback.format_exc())
        print("\nRESULT " + json.dumps(out), flush=True)
        return
    zip_path, workdir = sys.argv[1], sys.argv[2]
    try:
        import bpy

        ret = bpy.ops.extensions.package_install_files(
            filepath=zip_path, repo="user_default", enable_on_install=True
        )
        out["install_return"] = sorted(ret)
        out["enabled"] = ADDON in bpy.context.preferences.addons
        mod = sys.modules.get(ADDON)
        out["module_file"] = getattr(mod, "__file__", None)
        try:
            import embreex

            out["embreex_file"] = embreex.__file__
        except ImportError as err:
            out["embreex_error"] = str(err)
        # What Blender logged about the install (the operator's return value lies).
        if out["enabled"] and no_embree:
            check_no_embree(out)
        elif out["enabled"]:
            for step in (check_core, lambda o, p: check_operators(o, workdir)):
                try:
                    step(out, ADDON)
                except Exception:
                    out.setdefault("errors", []).append(traceback.format_exc())
    except Exception:
        out.setdefault("errors", []).append(traceback.format_exc())
    sys.stdout.flush()
    print("\nRESULT " + json.dumps(out), flush=True)


def exit_without_bpy_teardown_crash():
    """bpy 4.2 segfaults at interpreter exit in a process that enabled an extension
    add-on (even one disabled again): its static ``SpaceType`` destructor frees
    Python-defined UI classes (first Blender's own ``OUTLINER_PT_filter``) after Python
    was finalized (``PyGILState_Ensure`` with no interpreter). Fixed in 4.5. The report
    is printed; skip the teardown there."""
    import bpy

    sys.stdout.flush()
    sys.stderr.flush()
    if bpy.app.version < (4, 5, 0):
        os._exit(0)


if __name__ == "__main__":
    main()
    if "bpy" in sys.modules:
        exit_without_bpy_teardown_crash()
