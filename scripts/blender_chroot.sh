#!/usr/bin/env bash
# The real Blender application for the app test lane: a Debian trixie chroot with Debian's
# `blender` (4.3.x, Python 3.13, numpy 2.x), Xvfb, Mesa (software GL), ImageMagick and
# xdotool, cached in $FURCOLLIDE_CACHE/blender-trixie (outside the repository).
#
#   scripts/blender_chroot.sh            build it if missing (idempotent), print its root
#   scripts/blender_chroot.sh run CMD..  run CMD inside it, with /proc, /dev, /dev/shm and
#                                        $FURCOLLIDE_CHROOT_BIND (a host folder, mounted at
#                                        /work) in a private mount namespace that vanishes
#                                        with the command: no mount is ever left behind.
#
# Needs root (debootstrap, chroot, mount). The build takes ~5-10 minutes and ~1.6 GB; a
# finished chroot is reused as long as the package list below is unchanged (a stamp).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
. "$here/env_common.sh"

root="$FURCOLLIDE_CACHE/blender-trixie"
packages="blender python3-numpy xvfb xauth imagemagick libgl1-mesa-dri libglx-mesa0 xdotool \
ca-certificates"
want="$(printf 'trixie minbase %s v1' "$packages" | sha256sum | cut -d' ' -f1)"
stamp="$root/.furcollide-stamp"
log() { echo "blender_chroot: $*" >&2; }

build() {
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x "$root/usr/bin/blender" ]; then
    return 0
  fi
  need_root "building the Blender chroot"
  host_apt_install debootstrap
  local mirror tmp
  mirror="$(debian_mirror)"
  tmp="$root.partial"
  # A half-built chroot from an interrupted run is never reused.
  rm -rf --one-file-system "$tmp"
  log "debootstrap --variant=minbase trixie $tmp $mirror (a few minutes)"
  debootstrap --variant=minbase trixie "$tmp" "$mirror" >"$FURCOLLIDE_CACHE/debootstrap.log" 2>&1 \
    || { tail -20 "$FURCOLLIDE_CACHE/debootstrap.log" >&2; die "debootstrap trixie failed"; }
  echo "deb $mirror trixie main" > "$tmp/etc/apt/sources.list"
  log "apt-get install $packages"
  in_chroot "$tmp" env DEBIAN_FRONTEND=noninteractive sh -c \
    "apt-get update -q && apt-get install -y -q --no-install-recommends $packages && apt-get clean" \
    >"$FURCOLLIDE_CACHE/chroot-apt.log" 2>&1 \
    || { tail -20 "$FURCOLLIDE_CACHE/chroot-apt.log" >&2; die "apt-get install in the chroot failed"; }
  in_chroot "$tmp" blender --version >/dev/null 2>&1 || die "blender does not start in the chroot"
  echo "$want" > "$tmp/.furcollide-stamp"
  rm -rf --one-file-system "$root"
  mv "$tmp" "$root"
  log "ready: $root ($(in_chroot "$root" blender --version 2>/dev/null | head -n1))"
}

# in_chroot ROOT CMD...: run CMD in ROOT inside a private mount namespace.
in_chroot() {
  local r="$1"; shift
  local bind="${FURCOLLIDE_CHROOT_BIND:-}"
  mkdir -p "$r/work"
  unshare --mount --propagation private -- /bin/sh -ec '
    r="$1"; bind="$2"; shift 2
    mount -t proc proc "$r/proc"
    mount --rbind /dev "$r/dev"
    mount -t sysfs sys "$r/sys" 2>/dev/null || true
    [ -d /dev/shm ] && mount -t tmpfs shm "$r/dev/shm" 2>/dev/null || true
    if [ -n "$bind" ]; then mount --bind "$bind" "$r/work"; fi
    cp /etc/resolv.conf "$r/etc/resolv.conf" 2>/dev/null || true
    exec chroot "$r" "$@"' sh "$r" "$bind" "$@"
}

case "${1:-build}" in
  build)
    build
    echo "$root"
    ;;
  run)
    shift
    [ -f "$stamp" ] || die "the Blender chroot is not built ($root): run scripts/blender_chroot.sh"
    need_root "running the Blender chroot"
    in_chroot "$root" env -i HOME=/root PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8 "$@"
    ;;
  *)
    die "usage: $0 [build | run CMD...]"
    ;;
esac
