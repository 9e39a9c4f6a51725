#!/usr/bin/env bash
# Build CPython 3.13 once, from Debian trixie's python3.13 source package, into
# $FURCOLLIDE_CACHE/python3.13 (outside the repository), and print its interpreter path.
#
# bpy 5.1+ (5.2 LTS) wheels are cp313 only and this machine kind has no Python 3.13.
# Steps (all idempotent; a finished build is reused, ~0.1 s):
#   1. a private apt configuration with one line `deb-src <this machine's Debian mirror>
#      trixie main` (the machine's own apt sources are not touched);
#   2. `apt-get source --download-only python3.13`, then untar the upstream (orig) tarball;
#   3. `./configure --prefix=DIR --enable-shared LDFLAGS=-Wl,-rpath,DIR/lib`, `make -j2`,
#      `make install` (~5 min on 2 cores); the build dependencies come from apt.
# Exit status 1 with the missing piece named on any failure.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
. "$here/env_common.sh"

prefix="$FURCOLLIDE_CACHE/python3.13"
stamp="$prefix/.furcollide-built"
py="$prefix/bin/python3.13"
check='import sys, ssl, zlib, bz2, lzma, sqlite3, ctypes, readline, uuid, venv, ensurepip
assert sys.version_info[:2] == (3, 13), sys.version'
if [ -f "$stamp" ] && [ -x "$py" ] && "$py" -c "$check" 2>/dev/null; then
  echo "$py"
  exit 0
fi

log() { echo "build_python313: $*" >&2; }
host_apt_install build-essential dpkg-dev xz-utils libssl-dev zlib1g-dev libffi-dev libbz2-dev \
  liblzma-dev libsqlite3-dev libreadline-dev uuid-dev

mirror="$(debian_mirror)"
apt_dir="$FURCOLLIDE_CACHE/apt-trixie-src"
mkdir -p "$apt_dir/lists/partial" "$apt_dir/archives/partial" "$apt_dir/src"
echo "deb-src $mirror trixie main" > "$apt_dir/sources.list"
apt_opts=(-o "Dir::Etc::SourceList=$apt_dir/sources.list" -o "Dir::Etc::SourceParts=/dev/null"
  -o "Dir::State::Lists=$apt_dir/lists" -o "Dir::Cache::Archives=$apt_dir/archives"
  -o "APT::Sandbox::User=root")
cd "$apt_dir/src"
if ! ls python3.13_*.orig.tar.xz python3.13_*.orig.tar.gz >/dev/null 2>&1; then
  log "apt-get update (deb-src $mirror trixie main)"
  apt-get "${apt_opts[@]}" update -q >&2 || die "apt-get update of the trixie deb-src line ($mirror) failed"
  log "apt-get source --download-only python3.13"
  apt-get "${apt_opts[@]}" source --download-only python3.13 >&2 \
    || die "apt-get source python3.13 failed (is $mirror reachable?)"
fi
orig="$(ls python3.13_*.orig.tar.xz python3.13_*.orig.tar.gz 2>/dev/null | sort | tail -n1 || true)"
[ -n "$orig" ] || die "no python3.13 orig tarball in $apt_dir/src"

build="$FURCOLLIDE_CACHE/build-python3.13"
rm -rf "$build" "$prefix"
mkdir -p "$build"
log "unpack $orig"
tar -xf "$orig" -C "$build" --strip-components=1
cd "$build"
log "configure --enable-shared --prefix=$prefix"
./configure --prefix="$prefix" --enable-shared LDFLAGS="-Wl,-rpath,$prefix/lib" >configure.log 2>&1 \
  || { tail -20 configure.log >&2; die "configure failed (log: $build/configure.log)"; }
log "make -j2 (about 5 minutes on 2 cores)"
make -j2 >make.log 2>&1 || { tail -30 make.log >&2; die "make failed (log: $build/make.log)"; }
make install >install.log 2>&1 || { tail -30 install.log >&2; die "make install failed"; }
"$py" -c "$check" || die "the built Python lacks a standard module (see $build/make.log)"
cd /
rm -rf "$build"
date -u +%FT%TZ > "$stamp"
log "built $("$py" --version) in $prefix"
echo "$py"
