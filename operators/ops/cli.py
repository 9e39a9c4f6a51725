"""Command line: ``blender -b --command furcollide <action> FILE.blend [options]``.

Actions
-------
``bake``  bake every unbaked setup (``--frames A-B`` overrides the range,
          ``--object NAME`` restricts to one setup, ``--force`` frees old
          bakes first) and save the file (unless ``--no-save``).
``free``  free every bake (or ``--object``'s) and save.
``info``  print each setup, its range and cache state.

Exit codes: 0 success, 1 a bake/free failed, 2 bad arguments or file.
"""

from __future__ import annotations

import argparse
import os
import re
import sys

import bpy

from ...core import framecache
from ..store import bake, registry, report

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2


def _parser():
    p = argparse.ArgumentParser(
        prog="blender -b --command furcollide",
        description="Bake, free or inspect FurCollide setups of a .blend file.",
    )
    p.add_argument("action", choices=("bake", "free", "info"))
    p.add_argument("blend", help=".blend file to open (saved back after bake/free)")
    p.add_argument("--frames", help="frame range A-B or one frame A (overrides the setups' "
                   "ranges); a negative start needs the = form: --frames=-50-100")
    p.add_argument("--object", help="only the setup on this hair object")
    p.add_argument("--scene", help="scene name (default: the file's active scene)")
    p.add_argument("--force", action="store_true", help="free existing bakes first")
    p.add_argument("--no-save", action="store_true", help="do not save the .blend file")
    return p


#: ``A-B`` or ``A``; either may be negative (a pre-roll): ``--frames=-50-100``.
_FRAMES_RE = re.compile(r"^\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*)?$")


def _frames(text):
    m = _FRAMES_RE.match(text)
    if m is None:
        raise ValueError(
            f"--frames must look like 1-240, got {text!r} (negative: --frames=-50-100)"
        )
    a = int(m.group(1))
    b = a if m.group(2) is None else int(m.group(2))
    if b < a:
        raise ValueError(f"--frames end {b} is before start {a}")
    return a, b


def run(argv) -> int:
    """Entry point of the CLI command; returns the process exit code."""
    try:
        return _run(argv)
    except Exception as exc:  # noqa: BLE001 - a farm needs an exit code, not a traceback
        print(f"furcollide: failed: {report.describe(exc)}", file=sys.stderr)
        return EXIT_FAILED


def _run(argv) -> int:
    try:
        args = _parser().parse_args(list(argv))
    except SystemExit as exc:  # argparse exits on --help / errors
        return EXIT_OK if exc.code == 0 else EXIT_USAGE
    blend = os.path.abspath(args.blend)
    if not os.path.isfile(blend):
        print(f"furcollide: no such file: {blend}", file=sys.stderr)
        return EXIT_USAGE
    try:
        frames = _frames(args.frames) if args.frames is not None else None
    except ValueError as exc:
        print(f"furcollide: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        bpy.ops.wm.open_mainfile(filepath=blend)
    except RuntimeError as exc:
        print(f"furcollide: cannot open {blend}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    scene = bpy.data.scenes.get(args.scene) if args.scene else bpy.context.scene
    if scene is None:
        print(f"furcollide: no scene named {args.scene!r}", file=sys.stderr)
        return EXIT_USAGE
    sources = registry.setups(scene)
    # Setups whose hair is in this scene but that belong to another (registry.owner):
    # nothing here bakes or frees them, and saying so names the scene they belong to.
    elsewhere = [o for o in registry.setups(scene, owned=False) if o not in sources]
    if args.object:
        sources = [o for o in sources if o.name == args.object]
        elsewhere = [o for o in elsewhere if o.name == args.object]
        if not sources and not elsewhere:
            print(f"furcollide: no FurCollide setup on {args.object!r}", file=sys.stderr)
            return EXIT_USAGE
    if not sources:
        for ob in elsewhere:
            print(f"furcollide: {_set_up_elsewhere(ob, scene)}", file=sys.stderr)
        if not elsewhere:
            print(f"furcollide: no FurCollide setup in scene {scene.name!r}", file=sys.stderr)
        return EXIT_USAGE
    if args.action != "info":
        for ob in elsewhere:  # (left as they are)
            print(f"furcollide: {_set_up_elsewhere(ob, scene)}")

    if args.action == "info":
        for ob in elsewhere:
            print(f"{ob.name}: {_set_up_elsewhere(ob, scene)}")
        for ob in sources:
            s = ob.furcollide
            try:
                n = len(framecache.list_frames(bake.bake_directory(ob)))
            except ValueError:
                n = 0
            state = "baked" if s.is_baked else ("partial" if n else "not baked")
            print(
                f"{ob.name}: frames {s.frame_start}-{s.frame_end}, {state}, {n} files, "
                f"output {s.output.name if s.output else '-'}, colliders "
                f"{', '.join(c.object.name for c in s.colliders if c.object) or '-'}"
            )
        return EXIT_OK

    if args.action == "free" or args.force:
        for ob in sources:
            n = bake.free_bake(ob)
            print(f"furcollide: freed '{ob.name}' ({n} files)")
        if args.action == "free":
            return _save(args)

    todo = [o for o in sources if not o.furcollide.is_baked]
    if frames is not None:
        for ob in todo:
            ob.furcollide.frame_start, ob.furcollide.frame_end = frames
    if not todo:
        print("furcollide: every setup is already baked (use --force to re-bake)")
        return _save(args)
    try:
        job = bake.BakeJob(scene, todo, verbose=True)
        try:
            baked = job.run()
        except bake.BakeError:
            _save(args)  # keep bake_path so the next run resumes
            raise
    except bake.BakeError as exc:
        print(f"furcollide: bake failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    print(f"furcollide: baked {', '.join(o.name for o in baked)}")
    code = _save(args)
    return code if len(baked) == len(todo) else EXIT_FAILED


def _set_up_elsewhere(ob, scene) -> str:
    """Why the CLI leaves the setup on ``ob`` alone in ``scene``: it belongs to another."""
    own = registry.owner(ob, prefer=scene)
    return (f"{ob.name!r} is set up in scene {own.name!r}, not {scene.name!r} (a hair can "
            f"be set up in one scene only): use --scene {own.name!r}")


def _save(args) -> int:
    if args.no_save:
        return EXIT_OK
    try:
        bpy.ops.wm.save_mainfile()
    except RuntimeError as exc:
        print(f"furcollide: could not save: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


_handle = None


def register():
    global _handle
    fn = getattr(bpy.utils, "register_cli_command", None)
    if fn is None or _handle is not None:  # Blender < 4.2
        return
    try:
        _handle = fn("furcollide", run)
    except (ValueError, RuntimeError) as exc:
        print(f"FurCollide: command line not registered: {exc}")


def unregister():
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
