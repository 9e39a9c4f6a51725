"""The real-Blender lane (``make test-app``; part of ``make test``).

These tests build a Debian trixie chroot with Debian's Blender 4.3 (once, cached outside
the repository by ``scripts/blender_chroot.sh``) and drive the application with its UI
under Xvfb. They run only when ``FURCOLLIDE_APP=1`` (set by ``scripts/test_lanes.py``
for the ``app`` lane): the ``bpy`` lanes (4.2, 4.5, 5.0, 5.2) leave this folder out, so
``pytest tests`` in any venv keeps its meaning. In the app lane a missing piece (no
root, no debootstrap, no network) is a test failure naming it, never a skip.
"""

import os

if os.environ.get("FURCOLLIDE_APP") != "1":
    collect_ignore_glob = ["test_*.py"]
