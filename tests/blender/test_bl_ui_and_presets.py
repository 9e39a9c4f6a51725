"""The panels, operators' polls and messages, tooltips, presets (shipped, round trip,
broken files, an earlier version's), the settings mirroring ``core.Settings`` (angles
as Blender angles, choices in Blender's upper case) and the console messages."""

import dataclasses
import math
import os
import subprocess
import sys
import textwrap

import bpy
import numpy as np
import pytest
from helpers import activate, dense_groom, draw_panel, groom_scene, play, property_groups, set_core

pytestmark = pytest.mark.blender

PRESETS = "FURCOLLIDE_MT_presets"
PRESET_HEAD = (
    "import bpy\n"
    "fc = bpy.context.object.furcollide\n"
    "settings = fc.source.furcollide if fc.is_output and fc.source else fc\n"
)
SHIPPED = ["Short Fur (Stiff)", "Long Fur (Bend)", "Tight Cloth Contact (Soft)", "Grass Trampling"]


def _preset_folder():
    return bpy.utils.user_resource("SCRIPTS", path="presets/furcollide")


def _load(path):
    """Apply preset ``path`` as the preset menu does."""
    return bpy.ops.furcollide.preset_apply(filepath=path, menu_idname=PRESETS)


def _furcollide_operators():
    return [getattr(bpy.types, n) for n in dir(bpy.types) if n.startswith("FURCOLLIDE_OT_")]


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


def test_pipeline_panel_and_settings(fc):
    panel = bpy.types.FURCOLLIDE_PT_pipeline
    assert panel.bl_parent_id == "FURCOLLIDE_PT_main"
    hair, _ = dense_groom(fc)
    activate(hair)
    assert panel.poll(bpy.context)
    s = bpy.context.scene.furcollide_pipeline
    assert s.fraction == pytest.approx(0.15) and s.guides == 4
    for prop in s.bl_rna.properties:
        if prop.identifier not in {"rna_type", "name"}:
            assert len(prop.description) > 15, prop.identifier


def test_pipeline_panel_draws(fc):
    panel = bpy.types.FURCOLLIDE_PT_pipeline
    hair, _ = dense_groom(fc)
    box = bpy.data.objects["Box"]
    activate(hair)
    log = draw_panel(panel)
    assert ("operator", "furcollide.fur_sampler") in log
    assert ("operator", "furcollide.collider_distance") not in log
    fc.setup(hair, [box])
    activate(hair)
    log = draw_panel(panel)
    for idname in ("furcollide.fur_sampler", "furcollide.collider_distance",
                   "furcollide.children_from_guides"):
        assert ("operator", idname) in log
    for name in ("fraction", "seed", "use_selection", "area", "density", "guides"):
        assert ("prop", name) in log


def test_pipeline_panel_draws_the_stages(fc):

    guides, groom, box, out = groom_scene(fc)
    panel = bpy.types.FURCOLLIDE_PT_pipeline
    log = draw_panel(panel)
    for idname in ("furcollide.fur_attach_unbind", "furcollide.groom_bind",
                   "furcollide.groom_remove"):
        assert ("operator", idname) in log
    for name in ("use_wind", "wind_stage", "wind_strength", "use_jiggle", "jiggle_stage",
                 "use_region_of_influence", "roi_margin", "write_collider_distance",
                 "distance_max", "groom", "use_clearance"):
        assert ("prop", name) in log
    said = " ".join(v for k, v in log if k == "label")  # (notes wrap at the sidebar)
    assert "Restricts motion After Collision (none is on)" in said
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    guides.furcollide.motion.use_wind = True
    guides.furcollide.motion.use_region_of_influence = False
    log = draw_panel(panel)
    assert any(k == "label" and v and v.startswith("Render curves fixed") for k, v in log)
    said = " ".join(v for k, v in log if k == "label")
    assert "Motion after collision may push hair into colliders" in said


def test_preset_round_trip_restores_every_setting_exactly(fc):
    hair, box = fc.make_scene(frames=(1, 4))
    out = fc.setup(hair, [box])
    s = hair.furcollide
    names = fc.package.operators.settings.properties.SOLVER_PROPERTIES
    core_value = fc.settings.core_values.core_value
    look = dict(  # (the core's names and units)
        mode="soft", rotation_precision=0.7, max_angle=77.7, affected_connected_cvs=4,
        cv_falloff=0.33, attract_to_growth_surface=True, follow_collider_motion=True,
        shrink=True, scale_minimum=0.42,
        scale_angle=33.3, recovery_rate=0.123, plasticity=0.37,
        pinch_resolution="growth_surface", recover_pinched=False, collision_offset=0.0123,
    )
    assert set(look) == set(names)
    set_core(s, **look)
    saved = {k: getattr(s, k) for k in names}
    degrees = {k: core_value(s, k) for k in ("rotation_precision", "max_angle", "scale_angle")}
    assert degrees == {k: float(np.float32(look[k])) for k in degrees}  # (as typed)
    others = dict(threads=s.threads, frame_end=s.frame_end, wind=s.motion.wind_strength,
                  colliders=len(s.colliders))
    activate(out)  # saved from the output: it stores its source's settings
    assert bpy.ops.furcollide.preset_add(name="Round Trip 3") == {"FINISHED"}
    path = os.path.join(_preset_folder(), "Round_Trip_3.py")
    try:
        assert os.path.isfile(path)
        activate(hair)
        assert _load(os.path.join(_preset_folder(), "Short_Fur_(Stiff).py")) == {"FINISHED"}
        s.cv_falloff, s.attract_to_growth_surface, s.pinch_resolution = 0.9, False, "STOP"
        s.recover_pinched, s.affected_connected_cvs, s.shrink = True, 1, False
        s.follow_collider_motion = False
        assert all(getattr(s, k) != saved[k] for k in names)
        with open(path) as fh:
            written = fh.read()
        assert "furcollide_settings_version = 1" in written
        assert "settings.max_angle = math.radians(77.7)" in written  # readable degrees
        assert "settings.mode = 'SOFT'" in written
        assert _load(path) == {"FINISHED"}
        for k in names:
            assert getattr(s, k) == saved[k], k  # bit for bit
        assert degrees == {k: core_value(s, k) for k in degrees}
        assert others == dict(threads=s.threads, frame_end=s.frame_end,
                              wind=s.motion.wind_strength, colliders=len(s.colliders))
    finally:
        if os.path.exists(path):
            os.remove(path)


def test_broken_preset_files_report_clearly(fc, capsys):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 4))
    fc.setup(hair, [box])
    s = hair.furcollide
    activate(hair)
    folder = _preset_folder()
    written = []

    def preset(name, body):
        path = os.path.join(folder, f"Broken_{name}.py")
        with open(path, "w") as fh:
            fh.write(PRESET_HEAD + body)
        written.append(path)
        return path

    try:
        # a bad enum value: a clear error naming the value and the valid ones (an
        # earlier version's preset: its choices are read in upper case)
        p = preset("enum", "settings.mode = 'warp'\n")
        with pytest.raises(RuntimeError, match=r"Failed to execute the preset.*WARP.*STIFF"):
            _load(p)
        assert s.mode == "BEND"
        # a value of the wrong type
        p = preset("type", "settings.affected_connected_cvs = 'three'\n")
        with pytest.raises(RuntimeError, match="Failed to execute the preset.*expected an int"):
            _load(p)
        assert s.affected_connected_cvs == 2
        # a syntax error
        p = preset("syntax", "settings.max_angle = = 3\n")
        with pytest.raises(RuntimeError, match="Failed to execute the preset.*SyntaxError"):
            _load(p)
        # an unknown key (a newer or older version's setting) is ignored, the rest applies
        p = preset("unknown", "settings.wobble = 3\nsettings.plasticity = 0.25\n")
        assert _load(p) == {"FINISHED"}
        assert s.plasticity == pytest.approx(0.25)
        assert "wobble" not in s.keys()  # nothing stored in the file
        # out of range values are clamped to the property's limits (degrees: an earlier
        # version's preset)
        p = preset("range", "settings.max_angle = 1e9\nsettings.rotation_precision = -5.0\n")
        assert _load(p) == {"FINISHED"}
        core_value = fc.settings.core_values.core_value
        assert core_value(s, "max_angle") == 360.0 and s.max_angle == pytest.approx(2 * math.pi)
        assert core_value(s, "rotation_precision") == pytest.approx(0.001)
        # a non-finite value the properties accept: a clear status when solving, no crash
        p = preset("nan", "settings.max_angle = float('nan')\n")
        assert _load(p) == {"FINISHED"}
        play(scene, range(1, 3))
        level, msg = fc.store.report.status_for(hair)
        assert level == "ERROR" and "max_angle must be finite" in msg, msg
        # a good preset fixes it: the setup solves again from the start frame
        assert _load(os.path.join(folder, "Long_Fur_(Bend).py")) == {"FINISHED"}
        play(scene, range(1, 4))
        assert fc.store.report.status_for(hair) == ("INFO", "")
        # no active object: refused with the reason, not a crash
        bpy.context.view_layer.objects.active = None
        with pytest.raises(RuntimeError, match="no FurCollide setup"):
            _load(p)
    finally:
        for path in written:
            os.remove(path)
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err


def test_solver_properties_mirror_core_settings(fc):

    props = fc.settings.properties
    rna = bpy.types.Object.bl_rna.properties["furcollide"].fixed_type
    defaults = fc.core.Settings()
    for name in props.SOLVER_PROPERTIES:
        prop = rna.properties[name]
        default = prop.default
        if prop.subtype == "ANGLE":  # (Blender angles: radians)
            default = math.degrees(default)
        elif prop.type == "ENUM":  # (Blender's identifiers: upper case)
            default = default.lower()
        assert default == pytest.approx(getattr(defaults, name)), name
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    # (threads 0 -> None: all CPUs)
    got = dataclasses.asdict(fc.settings.fingerprints.core_settings(hair))
    assert got == pytest.approx(dataclasses.asdict(defaults))  # RNA floats are float32


def test_shipped_presets(fc):
    folder = bpy.utils.user_resource("SCRIPTS", path="presets/furcollide")
    names = {bpy.path.display_name(f) for f in os.listdir(folder)}
    for n in SHIPPED:
        assert n in names, names
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    path = os.path.join(folder, "Tight_Cloth_Contact_(Soft).py")
    assert _load(path) == {"FINISHED"}
    assert s.mode == "SOFT" and s.affected_connected_cvs == 3
    path = os.path.join(folder, "Grass_Trampling.py")
    assert _load(path) == {"FINISHED"}
    assert s.mode == "BEND" and s.plasticity == pytest.approx(0.6)
    assert s.recovery_rate == pytest.approx(0.05)
    assert fc.settings.core_values.core_value(s, "max_angle") == 170.0
    # a user preset round-trips
    s.max_angle = math.radians(33.0)
    assert bpy.ops.furcollide.preset_add(name="My Test") == {"FINISHED"}
    s.max_angle = math.pi
    assert _load(os.path.join(folder, "My_Test.py")) == {"FINISHED"}
    assert s.max_angle == pytest.approx(math.radians(33.0))
    assert fc.settings.core_values.core_value(s, "max_angle") == 33.0


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
        sys.path.insert(1, {os.path.dirname(conftest)!r})  # conftest imports helpers
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
        import os
        sys.stdout.flush()
        if bpy.app.version < (4, 5, 0):  # bpy 4.2 segfaults at exit (README, Tests)
            os._exit(0)
        """
    )
    env = dict(os.environ)
    env.pop("BLENDER_USER_RESOURCES", None)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "FurCollide needs the embreex ray tracer" in r.stdout
    assert "POLL:" in r.stdout and "embreex" in r.stdout.split("POLL:")[1]


def test_angles_are_blender_angles_shown_in_the_users_unit(fc):
    """Rotation Precision, Max Angle and Scale Angle (and no other setting is an angle)
    are Blender angles: radians, shown in the scene's rotation unit; their ranges are
    the core's in degrees."""
    rna = bpy.types.Object.bl_rna.properties["furcollide"].fixed_type
    angles = fc.settings.angles.ANGLES
    for name, (default, lo, hi) in angles.items():
        p = rna.properties[name]
        assert (p.type, p.subtype, p.unit) == ("FLOAT", "ANGLE", "ROTATION"), name
        assert p.default == pytest.approx(math.radians(default))
        assert (p.hard_min, p.hard_max) == pytest.approx((math.radians(lo), math.radians(hi)))
    others = [f"{g.identifier}.{p.identifier}" for g in property_groups() for p in g.properties
              if p.type == "FLOAT" and p.identifier not in angles and (
                  "angle" in p.name.lower() or "degree" in p.description.lower())]
    assert others == [], others
    # typed in degrees in the field, stored as typed (the core gets exactly that)
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    for deg in (0.25, 30.0, 77.7, 123.456, 359.9):
        s.max_angle = math.radians(deg)  # what the field sets
        assert s.to_core_kwargs()["max_angle"] == float(np.float32(deg)), deg
    s.max_angle = math.radians(1e6)
    assert s.to_core_kwargs()["max_angle"] == 360.0  # clamped as the field clamps


def test_every_choice_is_an_upper_case_identifier(fc):
    """One identifier style, Blender's own (``'BEND'``, ``'GROWTH_SURFACE'``, like
    ``ob.type == 'MESH'``): the core keeps its lower-case names, the glue translates."""
    lower = [f"{g.identifier}.{p.identifier}: {i.identifier}" for g in property_groups()
             for p in g.properties if p.type == "ENUM"
             for i in p.enum_items if i.identifier != i.identifier.upper()]
    assert lower == [], lower
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    s.mode, s.pinch_resolution = "STIFF", "GROWTH_SURFACE"
    kw = s.to_core_kwargs()
    assert (kw["mode"], kw["pinch_resolution"]) == ("stiff", "growth_surface")


def test_an_earlier_versions_preset_gives_the_same_settings_as_this_versions(fc, tmp_path):
    """The same look written by an earlier version (degrees, lower case, no version
    line) and by this one: applied, the settings are the same, bit for bit."""
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    activate(hair)
    old = tmp_path / "old.py"
    old.write_text(PRESET_HEAD + "settings.mode = 'stiff'\nsettings.rotation_precision = 0.3"
                   "\nsettings.max_angle = 150.0\nsettings.scale_angle = 45.5\n"
                   "settings.pinch_resolution = 'growth_surface'\n")
    assert _load(str(old)) == {"FINISHED"}
    names = fc.package.operators.settings.properties.SOLVER_PROPERTIES
    first = {k: getattr(s, k) for k in names}
    assert (s.mode, s.pinch_resolution) == ("STIFF", "GROWTH_SURFACE")
    core = s.to_core_kwargs()
    assert (core["rotation_precision"], core["max_angle"], core["scale_angle"]) == (
        float(np.float32(0.3)), 150.0, 45.5)
    assert bpy.ops.furcollide.preset_add(name="Same Look") == {"FINISHED"}
    new = os.path.join(_preset_folder(), "Same_Look.py")
    try:
        set_core(s, mode="bend", max_angle=90.0, rotation_precision=1.0, scale_angle=10.0)
        assert _load(new) == {"FINISHED"}
        assert {k: getattr(s, k) for k in names} == first
    finally:
        os.remove(new)
