#!/usr/bin/env bash
# Build CPython 3.13 (the Python of Blender 5.1 and 5.2) from Debian 13's source package,
# for machines whose distribution has no python3.13 (Debian 12). Prints the interpreter's path.
#
#   bash tools/build_python313.sh            # build once into ~/.cache/pdic/python3.13, then reuse
#   PDIC_PYTHON313_PREFIX=/opt/py313 bash tools/build_python313.sh
#
# The source comes from the Debian mirror this machine is already configured with (read from
# /etc/apt/sources.list*), through a private sources list and a private package-list folder:
# the system's apt configuration and package lists stay untouched. Takes about 2.5 minutes
# on 2 cores (configure + make -j2, no PGO); nothing is written into the repository.
set -euo pipefail

PREFIX="${PDIC_PYTHON313_PREFIX:-$HOME/.cache/pdic/python3.13}"
PYTHON="$PREFIX/bin/python3.13"
SUITE=trixie
# What CPython's configure needs for the modules bpy, pip and the tests use (ssl, zlib, ctypes,
# bz2, lzma, sqlite3, readline, expat); dpkg-dev unpacks the source package.
BUILD_DEPS=(build-essential dpkg-dev libssl-dev zlib1g-dev libffi-dev libbz2-dev liblzma-dev
            libsqlite3-dev libreadline-dev libexpat1-dev libncurses-dev uuid-dev)

say() { echo "build_python313: $*" >&2; }

# A complete build: the right version, the optional modules, and pip (what `python -m venv` seeds).
python_is_313() {
    "$1" -c 'import ssl, zlib, ctypes, bz2, lzma, sys; sys.exit(sys.version_info[:2] != (3, 13))' 2>/dev/null \
        && "$1" -m pip --version >/dev/null 2>&1
}

if [[ -x "$PYTHON" ]] && python_is_313 "$PYTHON"; then
    echo "$PYTHON"
    exit 0
fi

# The Debian mirror this machine uses: the first URI serving Debian's main archive
# (deb822 "URIs:" fields or one-line "deb URI suite" entries; the security archive is skipped).
debian_mirror() {
    local files=(/etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources)
    local uri
    uri=$(cat "${files[@]}" 2>/dev/null | grep -v '^\s*#' \
        | grep -oE '(URIs:\s*|^\s*deb(-src)?\s+(\[[^]]*\]\s+)?)https?://[^ ]+' \
        | grep -oE 'https?://[^ ]+' | grep -E '/debian/?$' | head -n1 || true)
    [[ -n "$uri" ]] || { say "error: no Debian archive URI in /etc/apt/sources.list*"; exit 1; }
    echo "${uri%/}"
}

missing=()
for pkg in "${BUILD_DEPS[@]}"; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if ((${#missing[@]})); then
    say "installing build dependencies: ${missing[*]}"
    apt-get update -qq >&2
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

start=$SECONDS
work=$(mktemp -d "${TMPDIR:-/tmp}/pdic-python313.XXXXXX")
trap 'rm -rf "$work"' EXIT
mirror=$(debian_mirror)
mkdir -p "$work/lists/partial" "$work/src"
echo "deb-src $mirror $SUITE main" >"$work/sources.list"
# Only source indices are fetched (no binary lists for another release), into the private folder.
APT_OPTS=(-o "APT::Sandbox::User=root" -o "Dir::Etc::SourceList=$work/sources.list" -o "Dir::Etc::SourceParts=/dev/null"
          -o "Dir::State::Lists=$work/lists" -o "Dir::Cache::pkgcache=" -o "Dir::Cache::srcpkgcache=")
say "fetching the python3.13 source package of Debian $SUITE from $mirror"
apt-get "${APT_OPTS[@]}" update -qq >&2
# apt verified the .dsc against the signed Release file (dpkg-source --no-check skips the
# maintainer signature, whose keyring Debian 12 does not install). Unpacked without Debian's
# patches: upstream CPython 3.13.5 as Blender uses it (Debian's patches disable ensurepip,
# hence venv's pip, and move site-packages to dist-packages).
(cd "$work/src" && apt-get "${APT_OPTS[@]}" source -qq --download-only python3.13 >/dev/null \
    && dpkg-source -x --no-check --skip-patches python3.13_*.dsc >/dev/null)
srcdir=$(find "$work/src" -mindepth 1 -maxdepth 1 -type d -name 'python3.13-*' | head -n1)
[[ -n "$srcdir" ]] || { say "error: apt-get source python3.13 unpacked nothing"; exit 1; }
say "building $(basename "$srcdir") into $PREFIX (configure + make -j2)"
(
    cd "$srcdir"
    ./configure --prefix="$PREFIX" --with-ensurepip=install >"$work/configure.log" 2>&1 \
        || { tail -n 30 "$work/configure.log" >&2; exit 1; }
    make -j2 >"$work/make.log" 2>&1 || { tail -n 30 "$work/make.log" >&2; exit 1; }
    rm -rf "$PREFIX"
    make altinstall >"$work/install.log" 2>&1 || { tail -n 30 "$work/install.log" >&2; exit 1; }
)
python_is_313 "$PYTHON" || { say "error: $PYTHON lacks ssl, zlib, ctypes, bz2, lzma or pip"; exit 1; }
say "built $("$PYTHON" --version) in $((SECONDS - start)) s"
echo "$PYTHON"
