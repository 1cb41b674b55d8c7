#!/usr/bin/env bash
# Fetch Mesa 25's software Vulkan driver (lavapipe) from Debian bookworm-backports into a local
# folder, without root and without touching the system's apt sources, and print the environment
# variable that points the Vulkan loader at it.
#
# Why: SAPIEN 3.0.3 (ManiSkill's renderer) needs the Vulkan feature descriptorBindingPartiallyBound,
# which Debian 12's own lavapipe (Mesa 22.3.6) lacks; Mesa 25.0.7's has it. With it, ManiSkill
# suites can render cameras on CPU (`obs=rgb`); without it they run on state observations only.
#
# usage: scripts/fetch_lavapipe.sh [DEST]      (DEST default: ${XDG_CACHE_HOME:-~/.cache}/bench/lavapipe)
#   then: export VK_ICD_FILENAMES=DEST/lvp_icd.json   (the script prints the exact line)
# env: DEBIAN_MIRROR (default http://deb.debian.org/debian), MESA_VERSION (default 25.0.7-2~bpo12+1)
set -euo pipefail

if [[ "${1:-}" == "-h" || "${1:-}" == "--help" ]]; then
    sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'
    exit 0
fi
DEST="${1:-${XDG_CACHE_HOME:-$HOME/.cache}/bench/lavapipe}"
MIRROR="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
VERSION="${MESA_VERSION:-25.0.7-2~bpo12+1}"
KEYRING=/usr/share/keyrings/debian-archive-keyring.gpg

die() { echo "fetch_lavapipe: $*" >&2; exit 2; }
command -v apt-get >/dev/null || die "apt-get not found: this script needs a Debian 12 (bookworm) system"
command -v dpkg >/dev/null || die "dpkg not found: this script needs a Debian 12 (bookworm) system"
[[ -r "$KEYRING" ]] || die "$KEYRING not readable: install debian-archive-keyring"
if [[ -r /etc/os-release ]] && ! grep -q 'VERSION_CODENAME=bookworm' /etc/os-release; then
    echo "fetch_lavapipe: warning: not Debian 12 (bookworm); the backported driver may not load" >&2
fi

ICD="$DEST/lvp_icd.json"
LIB="$DEST/root/usr/lib/x86_64-linux-gnu/libvulkan_lvp.so"
if [[ -f "$ICD" && -f "$LIB" ]]; then
    echo "lavapipe already in $DEST" >&2
else
    mkdir -p "$DEST"
    APT="$DEST/apt"
    mkdir -p "$APT/lists/partial" "$APT/cache/archives/partial"
    echo "deb [signed-by=$KEYRING] $MIRROR bookworm-backports main" > "$APT/sources.list"
    opts=(-o "Dir::Etc::SourceList=$APT/sources.list" -o "Dir::Etc::SourceParts=/dev/null"
          -o "Dir::State::Lists=$APT/lists" -o "Dir::Cache=$APT/cache" -o "Debug::NoLocking=1"
          -o "APT::Sandbox::User=$(id -un)")
    echo "fetching the bookworm-backports index from $MIRROR ..." >&2
    apt-get "${opts[@]}" -qq update >&2 || die "apt-get update of bookworm-backports failed (is $MIRROR reachable?)"
    echo "downloading mesa-vulkan-drivers=$VERSION ..." >&2
    (cd "$DEST" && apt-get "${opts[@]}" -qq download "mesa-vulkan-drivers=$VERSION" >&2) \
        || die "apt-get download mesa-vulkan-drivers=$VERSION failed"
    deb=$(ls "$DEST"/mesa-vulkan-drivers_*.deb | head -n1)
    rm -rf "$DEST/root"
    dpkg -x "$deb" "$DEST/root"
    [[ -f "$LIB" ]] || die "the package has no $LIB"
    src_icd=$(ls "$DEST"/root/usr/share/vulkan/icd.d/lvp_icd*.json | head -n1)
    # the packaged manifest names the library by bare file name: point it at the extracted copy
    python3 - "$src_icd" "$LIB" "$ICD" <<'PY'
import json, sys
src, lib, out = sys.argv[1:]
manifest = json.load(open(src))
manifest["ICD"]["library_path"] = lib
json.dump(manifest, open(out + ".tmp", "w"), indent=2)
PY
    mv "$ICD.tmp" "$ICD"
    rm -rf "$APT" "$deb"
fi

missing=$(ldd "$LIB" | awk '/not found/ {print $1}' | tr '\n' ' ')
[[ -z "$missing" ]] || die "libvulkan_lvp.so needs libraries this system lacks: $missing(install them with apt)"
ldconfig -p 2>/dev/null | grep -q 'libvulkan.so.1' || echo "fetch_lavapipe: warning: the Vulkan loader (libvulkan1) is not installed" >&2
echo "export VK_ICD_FILENAMES=$ICD"
