"""Panel registration, presets, poll messages, tooltips, missing ray tracer."""

import os
import subprocess
import sys
import textwrap

import bpy
import pytest

pytestmark = pytest.mark.blender

SHIPPED = ["Short Fur (Stiff)", "Long Fur (Bend)", "Tight Cloth Contact (Soft)", "Grass Trampling"]


def test_panels_registered_and_poll(fc):
    for name in ("FURCOLLIDE_PT_main", "FURCOLLIDE_PT_colliders", "FURCOLLIDE_PT_cache",
                 "FURCOLLIDE_PT_stats", "FURCOLLIDE_UL_colliders", "FURCOLLIDE_MT_presets"):
        assert hasattr(bpy.types, name), name
    main = bpy.types.FURCOLLIDE_PT_main
    assert main.bl_category == "FurCollide" and main.bl_region_type == "UI"
    hair, box = fc.make_scene()
    bpy.context.view_layer.objects.active = hair
    assert main.poll(bpy.context)
    assert not bpy.types.FURCOLLIDE_PT_cache.poll(bpy.context)
    out = fc.setup(hair, [box])
    assert bpy.types.FURCOLLIDE_PT_cache.poll(bpy.context)
    bpy.context.view_layer.objects.active = out  # the output shows the same setup
    assert bpy.types.FURCOLLIDE_PT_cache.poll(bpy.context)


def test_every_property_has_a_tooltip():
    settings = bpy.types.Object.bl_rna.properties["furcollide"].fixed_type
    collider = settings.properties["colliders"].fixed_type
    motion = settings.properties["motion"].fixed_type
    groom = settings.properties["groom"].fixed_type
    pipeline = bpy.types.Scene.bl_rna.properties["furcollide_pipeline"].fixed_type
    for cls in (settings, collider, motion, groom, pipeline):
        for prop in cls.properties:
            if prop.identifier in {"rna_type", "name"}:
                continue
            assert len(prop.description) > 15, f"{cls.identifier}.{prop.identifier}"
    for enum in (settings.properties["mode"], settings.properties["pinch_resolution"],
                 motion.properties["wind_stage"], motion.properties["jiggle_stage"]):
        for item in enum.enum_items:
            assert len(item.description) > 15, item.identifier


def _furcollide_operators():
    return [getattr(bpy.types, n) for n in dir(bpy.types) if n.startswith("FURCOLLIDE_OT_")]


def test_every_operator_polls_with_a_message_and_runs_synchronously():
    ops = _furcollide_operators()
    names = {op.bl_idname for op in ops}
    assert {"furcollide.add", "furcollide.remove", "furcollide.collider_add",
            "furcollide.collider_remove", "furcollide.bake", "furcollide.bake_all",
            "furcollide.free_bake", "furcollide.free_bake_all", "furcollide.reset",
            "furcollide.preset_add"} <= names
    for op in ops:
        assert callable(getattr(op, "poll", None)), op.bl_idname
        assert callable(getattr(op, "execute", None)), op.bl_idname  # headless + tests
        assert len(op.__doc__ or "") > 15, op.bl_idname  # the button's tooltip
    for idname in sorted(names):
        mod, name = idname.split(".")
        operator = getattr(getattr(bpy.ops, mod), name)
        for prop in operator.get_rna_type().properties:
            if prop.identifier != "rna_type" and not prop.is_hidden:
                assert len(prop.description) > 15, f"{idname}.{prop.identifier}"
        # With nothing to act on, every operator refuses and says why (poll_message_set).
        with pytest.raises(RuntimeError) as err:
            operator()
        assert "context is incorrect" not in str(err.value), idname
        assert len(str(err.value).split("poll()", 1)[1].strip()) > 10, str(err.value)


def test_poll_refusals_say_why(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    bpy.context.view_layer.objects.active = out
    with pytest.raises(RuntimeError, match="is a FurCollide output"):
        bpy.ops.furcollide.add()
    bpy.context.view_layer.objects.active = hair
    with pytest.raises(RuntimeError, match="already has a FurCollide setup"):
        bpy.ops.furcollide.add()
    with pytest.raises(RuntimeError, match="Nothing baked"):
        bpy.ops.furcollide.free_bake()
    hair.furcollide.enabled = False
    with pytest.raises(RuntimeError, match="disabled: enable it to bake"):
        bpy.ops.furcollide.bake()


def test_poll_messages(fc):
    with pytest.raises(RuntimeError, match="must be a hair Curves object"):
        bpy.ops.furcollide.add()
    with pytest.raises(RuntimeError, match="no FurCollide setup"):
        bpy.ops.furcollide.bake()
    with pytest.raises(RuntimeError, match="No baked FurCollide setup"):
        bpy.ops.furcollide.free_bake_all()


def test_collider_add_remove(fc):
    hair, box = fc.make_scene()
    fc.setup(hair, [])
    s = hair.furcollide
    assert len(s.colliders) == 0
    box.select_set(True)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    assert [c.object for c in s.colliders] == [box]
    assert s.stat_frame == 1 and not s.is_outdated  # refreshed at once
    for f in range(2, 7):
        bpy.context.scene.frame_set(f)
    assert s.stat_colliding > 0
    assert bpy.ops.furcollide.collider_remove() == {"FINISHED"}
    assert len(s.colliders) == 0
    with pytest.raises(RuntimeError, match="No collider selected"):
        bpy.ops.furcollide.collider_remove()
    # a collider collection works too
    coll = bpy.data.collections.new("Colliders")
    bpy.context.scene.collection.children.link(coll)
    coll.objects.link(box)
    s.collider_collection = coll
    for f in range(1, 7):
        bpy.context.scene.frame_set(f)
    assert s.stat_colliding > 0


def test_show_result_toggle(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    assert hair.hide_get() and not out.hide_get()
    hair.furcollide.show_result = False
    assert not hair.hide_get() and out.hide_get()
    hair.furcollide.show_result = True
    assert hair.hide_get() and not out.hide_get()


def test_errors_print_one_console_line(fc, capsys):
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    hair.furcollide.attract_to_growth_surface = True  # no Surface object: an error
    capsys.readouterr()
    for f in range(1, 8):
        bpy.context.scene.frame_set(f)
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "FurCollide 'Fur'" in ln]
    assert len(lines) <= 2, lines  # the error, then (at most) the "not solved" variant
    assert "Surface" in hair.furcollide.status_message


def test_remove_setup(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    name = out.name
    assert bpy.ops.furcollide.remove() == {"FINISHED"}
    assert name not in bpy.data.objects
    assert not hair.furcollide.is_setup and not hair.hide_render


def test_shipped_presets(fc):
    folder = bpy.utils.user_resource("SCRIPTS", path="presets/furcollide")
    names = {bpy.path.display_name(f) for f in os.listdir(folder)}
    for n in SHIPPED:
        assert n in names, names
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    path = os.path.join(folder, "Tight_Cloth_Contact_(Soft).py")
    bpy.ops.script.execute_preset(filepath=path, menu_idname="FURCOLLIDE_MT_presets")
    assert s.mode == "soft" and s.affected_connected_cvs == 3
    path = os.path.join(folder, "Grass_Trampling.py")
    bpy.ops.script.execute_preset(filepath=path, menu_idname="FURCOLLIDE_MT_presets")
    assert s.mode == "bend" and s.plasticity == pytest.approx(0.6)
    assert s.recovery_rate == pytest.approx(0.05)
    # a user preset round-trips
    s.max_angle = 33.0
    assert bpy.ops.furcollide.preset_add(name="My Test") == {"FINISHED"}
    s.max_angle = 180.0
    bpy.ops.script.execute_preset(
        filepath=os.path.join(folder, "My_Test.py"), menu_idname="FURCOLLIDE_MT_presets"
    )
    assert s.max_angle == pytest.approx(33.0)


def test_missing_ray_tracer_reports_clearly(tmp_path):
    """Enabling the add-on where embreex cannot load must not crash."""
    stub = tmp_path / "stub" / "embreex"
    stub.mkdir(parents=True)
    (stub / "__init__.py").write_text(
        "raise ImportError('simulated: no embreex wheel for this platform')\n"
    )
    conftest = os.path.join(os.path.dirname(__file__), "conftest.py")
    code = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(tmp_path / 'stub')!r})
        import importlib.util
        spec = importlib.util.spec_from_file_location("fcconf", {conftest!r})
        conf = importlib.util.module_from_spec(spec); spec.loader.exec_module(conf)
        import bpy, addon_utils
        repos = bpy.context.preferences.extensions.repos
        repos.new(name="fcdev", module="fcdev", custom_directory=str(conf.DEV_DIR),
                  source="USER")
        mod = addon_utils.enable(conf.ADDON, default_set=True, handle_error=None)
        assert mod is not None
        hc = bpy.data.hair_curves.new("h"); hc.add_curves([3])
        ob = bpy.data.objects.new("h", hc); bpy.context.scene.collection.objects.link(ob)
        bpy.context.view_layer.objects.active = ob
        try:
            bpy.ops.furcollide.add()
        except RuntimeError as exc:
            print("POLL:", exc)
        """
    )
    env = dict(os.environ)
    env.pop("BLENDER_USER_RESOURCES", None)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "FurCollide needs the embreex ray tracer" in r.stdout
    assert "POLL:" in r.stdout and "embreex" in r.stdout.split("POLL:")[1]


def test_disable_enable_cleans_up_and_keeps_data(fc):
    import addon_utils

    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    hair.furcollide.plasticity = 0.7
    name = fc.package.__name__
    addon_utils.disable(name, default_set=True)
    try:
        for lst in (bpy.app.handlers.frame_change_post, bpy.app.handlers.load_post,
                    bpy.app.handlers.depsgraph_update_post):
            assert not any("furcollide" in getattr(h, "__module__", "") for h in lst)
        assert not hasattr(bpy.types.Object, "furcollide")
        assert not hasattr(bpy.types, "FURCOLLIDE_OT_add")
        assert not hasattr(bpy.types, "FURCOLLIDE_PT_main")
        bpy.context.scene.frame_set(3)  # nothing runs, nothing breaks
    finally:
        assert addon_utils.enable(name, default_set=True, handle_error=None) is not None
    s = bpy.data.objects["Fur"].furcollide
    assert s.is_setup and s.plasticity == pytest.approx(0.7)
    bpy.context.scene.frame_set(1)
    assert s.stat_frame == 1


def test_collider_collection_holding_everything(fc):
    hair, box = fc.make_scene()
    coll = bpy.data.collections.new("Everything")
    bpy.context.scene.collection.children.link(coll)
    out = fc.setup(hair, [])
    for o in (hair, box, out):
        coll.objects.link(o)
    hair.furcollide.collider_collection = coll
    for f in range(1, 8):
        bpy.context.scene.frame_set(f)
        assert hair.furcollide.status_message == ""
    assert hair.furcollide.stat_colliding > 0
    names = {r.name for r in fc.colliders.collider_objects(hair)}
    assert names == {"Box"}
