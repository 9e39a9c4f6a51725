# Shared by the scripts that build the test environments outside the repository.
# Source it: `. "$(dirname "$0")/env_common.sh"`.
#
# FURCOLLIDE_CACHE  where the environments live (default /var/cache/furcollide when it
#                   can be created, else ~/.cache/furcollide). Never inside the repo:
#                   the chroot is ~1.5 GB and every bpy venv ~1 GB.
# FURCOLLIDE_MIRROR the Debian mirror (default: the first http(s) Debian URI in the
#                   machine's own apt sources, else http://deb.debian.org/debian).

if [ -z "${FURCOLLIDE_CACHE:-}" ]; then
  if mkdir -p /var/cache/furcollide 2>/dev/null && [ -w /var/cache/furcollide ]; then
    FURCOLLIDE_CACHE=/var/cache/furcollide
  else
    FURCOLLIDE_CACHE="$HOME/.cache/furcollide"
  fi
fi
export FURCOLLIDE_CACHE
mkdir -p "$FURCOLLIDE_CACHE"

debian_mirror() {
  if [ -n "${FURCOLLIDE_MIRROR:-}" ]; then echo "$FURCOLLIDE_MIRROR"; return; fi
  local uri
  uri="$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources \
        2>/dev/null | grep -oE 'https?://[^ ]+/debian/?( |$)' | grep -v security | head -n1 | tr -d ' ')"
  echo "${uri:-http://deb.debian.org/debian}" | sed 's:/*$::'
}

die() {
  echo "$(basename "$0"): ERROR: $*" >&2
  exit 1
}

need_root() {
  [ "$(id -u)" = 0 ] || die "$1 needs root (apt-get / debootstrap / chroot); run as root or with sudo"
}

# Install Debian packages on this machine if any is missing (loud on failure).
host_apt_install() {
  local missing=()
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  need_root "installing ${missing[*]}"
  echo "$(basename "$0"): apt-get install ${missing[*]}" >&2
  apt-get update -q >&2 || die "apt-get update failed"
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}" >&2 \
    || die "apt-get install ${missing[*]} failed"
}
