#!/usr/bin/env bash
# Create (or reuse) the venv of one test lane and print its interpreter path.
#
#   scripts/lane_venv.sh 5.0   the main lane: the repository's .venv (scripts/bootstrap.sh,
#                              requirements-dev.txt: bpy 5.0.1, Python 3.11)
#   scripts/lane_venv.sh 4.2   bpy 4.2.x LTS  (requirements/bpy-4.2.txt, Python 3.11)
#   scripts/lane_venv.sh 4.5   bpy 4.5.x LTS  (requirements/bpy-4.5.txt, Python 3.11)
#   scripts/lane_venv.sh 5.2   bpy 5.2.x LTS  (requirements/bpy-5.2.txt, Python 3.13 from
#                              scripts/build_python313.sh)
#
# The 4.2/4.5/5.2 venvs live in $FURCOLLIDE_CACHE/venvs (outside the repository, ~1 GB
# each) and are rebuilt only when their requirements file changes (a stamp). Exit 1 with
# what is missing when a lane cannot be prepared.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(dirname "$here")"
. "$here/env_common.sh"
lane="${1:?usage: lane_venv.sh 4.2|4.5|5.0|5.2}"

if [ "$lane" = 5.0 ]; then
  "$here/bootstrap.sh" >&2 || die "the main lane's .venv could not be bootstrapped"
  echo "$root/.venv/bin/python"
  exit 0
fi
req="$root/requirements/bpy-$lane.txt"
[ -f "$req" ] || die "unknown lane '$lane' (no $req)"
case "$lane" in
  5.2) py="$("$here/build_python313.sh")" || die "lane 5.2 needs CPython 3.13, whose build failed" ;;
  *)
    py="${PYTHON:-python3.11}"
    command -v "$py" >/dev/null 2>&1 || py=python3
    "$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null \
      || die "lane $lane needs Python 3.11 (bpy $lane wheels are cp311); found $("$py" --version 2>&1)"
    ;;
esac
venv="$FURCOLLIDE_CACHE/venvs/bpy-$lane"
stamp="$venv/.requirements.sha"
want="$( (cat "$req"; "$py" -c 'import sys; print(sys.version)') | sha256sum | cut -d' ' -f1)"
if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  echo "$venv/bin/python"
  exit 0
fi
echo "lane_venv: creating $venv from requirements/bpy-$lane.txt" >&2
rm -rf "$venv"
"$py" -m venv "$venv" || die "python -m venv failed for lane $lane"
"$venv/bin/python" -m pip install --disable-pip-version-check -q --upgrade pip >&2 || true
"$venv/bin/python" -m pip install --disable-pip-version-check -q -r "$req" >&2 \
  || die "pip install -r requirements/bpy-$lane.txt failed (lane $lane)"
echo "$want" > "$stamp"
echo "$venv/bin/python"
