#!/usr/bin/env bash
# Build the Kinect V2 SDK (libfreenect2 + its Python binding pylibfreenect2) from the unmodified
# upstream archives in ../shared/vendor/kinect/ into the ACTIVE Python environment: the virtual
# environment when one is active, else the running Python's own prefix (CI, as root). No root needed
# for a venv. libfreenect2 goes to <prefix>/libfreenect2/ (CPU pipeline only: no OpenGL/OpenCL/CUDA),
# pylibfreenect2 is pip-installed with an rpath to it. pylibfreenect2 is patched first with
# scripts/patches/pylibfreenect2/*.patch (see the README there); the archives are never edited.
#
# Usage: bash scripts/install_kinect_sdk.sh            (PYTHON=/path/to/python to pick the interpreter)
# Environment: CALIBGRAPH_KINECT_VENDOR=<dir with the two archives> overrides ../shared/vendor/kinect.
# A second run with the same archives, patches, script and Python is a no-op (a stamp file records them).
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
PY=${PYTHON:-$(command -v python || command -v python3 || true)}
LIBFREENECT2_TGZ=libfreenect2-fd64c5d.tar.gz
PYLIBFREENECT2_TGZ=pylibfreenect2-40221e8.tar.gz
CMAKE_FLAGS=(-DCMAKE_BUILD_TYPE=Release -DENABLE_CXX11=ON -DENABLE_OPENGL=OFF -DENABLE_OPENCL=OFF
             -DENABLE_CUDA=OFF -DENABLE_VAAPI=OFF -DENABLE_TEGRAJPEG=OFF -DBUILD_EXAMPLES=OFF
             -DBUILD_OPENNI2_DRIVER=OFF -DCMAKE_INSTALL_LIBDIR=lib)

die() { echo "install_kinect_sdk: $*" >&2; exit 1; }

# -- where from, where to -------------------------------------------------------------------------
[ -n "$PY" ] || die "no python on PATH; activate the virtual environment first (or set PYTHON=...)."
VENDOR=${CALIBGRAPH_KINECT_VENDOR:-}
if [ -z "$VENDOR" ]; then
    for d in "$REPO/../shared/vendor/kinect" "$REPO/shared/vendor/kinect"; do
        [ -f "$d/$LIBFREENECT2_TGZ" ] && { VENDOR=$(cd "$d" && pwd); break; }
    done
fi
[ -n "$VENDOR" ] && [ -f "$VENDOR/$LIBFREENECT2_TGZ" ] && [ -f "$VENDOR/$PYLIBFREENECT2_TGZ" ] \
    || die "$LIBFREENECT2_TGZ and $PYLIBFREENECT2_TGZ not found in ${VENDOR:-../shared/vendor/kinect beside the checkout} (set CALIBGRAPH_KINECT_VENDOR)."
PREFIX=$("$PY" -c 'import sys; print(sys.prefix)')
DEST="$PREFIX/libfreenect2"
PATCHES=("$REPO"/scripts/patches/pylibfreenect2/*.patch)

# -- already done? ------------------------------------------------------------------------------
STAMP_WANT=$( { sha256sum "$VENDOR/$LIBFREENECT2_TGZ" "$VENDOR/$PYLIBFREENECT2_TGZ" "${PATCHES[@]}" "${BASH_SOURCE[0]}" | cut -d" " -f1;
                echo "${CMAKE_FLAGS[*]}"; "$PY" -c 'import sys; print(sys.version)'; } | sha256sum | cut -d' ' -f1)
if [ -f "$DEST/.calibgraph-stamp" ] && [ "$(cat "$DEST/.calibgraph-stamp")" = "$STAMP_WANT" ] \
   && "$PY" -c 'import pylibfreenect2; pylibfreenect2.Freenect2Replay' 2>/dev/null; then
    echo "install_kinect_sdk: libfreenect2 and pylibfreenect2 already installed in $PREFIX (nothing to do)."
    exit 0
fi

# -- system build dependencies: name every missing one in one line --------------------------------
missing=()
command -v cmake >/dev/null || missing+=("cmake")
command -v make >/dev/null || missing+=("make")
command -v c++ >/dev/null || command -v g++ >/dev/null || missing+=("a C++ compiler (g++)")
command -v pkg-config >/dev/null || missing+=("pkg-config")
command -v patch >/dev/null || missing+=("patch")
if command -v pkg-config >/dev/null; then
    pkg-config --exists 'libusb-1.0 >= 1.0.20' || missing+=("libusb-1.0 headers (libusb-1.0-0-dev)")
fi
if ! { command -v pkg-config >/dev/null && pkg-config --exists libturbojpeg; } \
   && ! ls /usr/include/turbojpeg.h /usr/local/include/turbojpeg.h >/dev/null 2>&1; then
    missing+=("TurboJPEG (libturbojpeg0-dev)")
fi
"$PY" - <<'EOF' || missing+=("Python headers (python3-dev)")
import os, sys, sysconfig
sys.exit(0 if os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else 1)
EOF
"$PY" -c 'import numpy' 2>/dev/null || missing+=("numpy in $PY (pip install numpy)")
if [ ${#missing[@]} -gt 0 ]; then
    joined=$(printf ', %s' "${missing[@]}")
    die "missing build dependencies: ${joined:2}. On Debian/Ubuntu: apt-get install cmake make g++ pkg-config patch libusb-1.0-0-dev libturbojpeg0-dev python3-dev"
fi

# -- build ----------------------------------------------------------------------------------------
WORK=$(mktemp -d "${TMPDIR:-/tmp}/calibgraph-kinect.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
JOBS=$(nproc 2>/dev/null || echo 2)
t0=$(date +%s)
echo "install_kinect_sdk: building libfreenect2 into $DEST ..."
mkdir -p "$WORK/libfreenect2"
tar -xzf "$VENDOR/$LIBFREENECT2_TGZ" -C "$WORK/libfreenect2"
rm -rf "$DEST"
cmake -S "$WORK/libfreenect2" -B "$WORK/build" "${CMAKE_FLAGS[@]}" -DCMAKE_INSTALL_PREFIX="$DEST" \
    >"$WORK/cmake.log" 2>&1 || { tail -n 30 "$WORK/cmake.log" >&2; die "libfreenect2: cmake failed (log above)."; }
cmake --build "$WORK/build" -j "$JOBS" >"$WORK/build.log" 2>&1 \
    || { tail -n 30 "$WORK/build.log" >&2; die "libfreenect2: build failed (log above)."; }
cmake --install "$WORK/build" >"$WORK/install.log" 2>&1 \
    || { tail -n 30 "$WORK/install.log" >&2; die "libfreenect2: install failed (log above)."; }
# licences kept beside the library (Apache-2.0 or GPL-2.0, contributors)
cp "$WORK/libfreenect2/APACHE20" "$WORK/libfreenect2/GPL2" "$WORK/libfreenect2/CONTRIB" "$DEST/"
cp "$WORK/libfreenect2/platform/linux/udev/90-kinect2.rules" "$DEST/"
echo "install_kinect_sdk: libfreenect2 built in $(( $(date +%s) - t0 )) s."

t1=$(date +%s)
echo "install_kinect_sdk: patching and installing pylibfreenect2 into $PREFIX ..."
tar -xzf "$VENDOR/$PYLIBFREENECT2_TGZ" -C "$WORK"
for p in "${PATCHES[@]}"; do
    patch -s -p1 -d "$WORK/pylibfreenect2" <"$p" || die "pylibfreenect2: patch $(basename "$p") does not apply."
done
# build tools in the target environment, only those missing (a second run needs no network):
# Cython >= 3, and bdist_wheel (setuptools >= 70.1 has it, older ones need the wheel package)
need=$("$PY" - 2>/dev/null <<'EOF'
from importlib.metadata import version, PackageNotFoundError
def v(name):
    try:
        return tuple(int(x) for x in version(name).split(".")[:2] if x.isdigit())
    except PackageNotFoundError:
        return None
need = []
if (v("cython") or (0,)) < (3,):
    need.append("cython>=3")
if (v("setuptools") or (0,)) < (70, 1) and v("wheel") is None:
    need.append("wheel")
print(" ".join(need))
EOF
)
if [ -n "$need" ]; then
    echo "install_kinect_sdk: installing build tools into $PREFIX: $need"
    # shellcheck disable=SC2086
    "$PY" -m pip install -q $need || die "cannot pip install $need (needed to build pylibfreenect2)."
fi
# -g0: no debug info for the 60k-line generated C++ (halves its compile time)
CFLAGS="${CFLAGS:-} -g0" CXXFLAGS="${CXXFLAGS:-} -g0" \
LIBFREENECT2_INSTALL_PREFIX="$DEST" LIBFREENECT2_INTERNAL_INCLUDE="$WORK/libfreenect2/include/internal" \
    "$PY" -m pip install -q --no-build-isolation --no-deps --force-reinstall "$WORK/pylibfreenect2" \
    >"$WORK/pip.log" 2>&1 || { tail -n 40 "$WORK/pip.log" >&2; die "pylibfreenect2: build failed (log above)."; }
(cd "$WORK" && "$PY" -c 'import pylibfreenect2 as f; f.setGlobalLogger(None); f.Freenect2Replay; print("install_kinect_sdk: pylibfreenect2", f.__version__, "imports;", f.Freenect2().enumerateDevices(), "Kinect V2 connected.")') \
    || die "pylibfreenect2 was built but does not import."
echo "install_kinect_sdk: pylibfreenect2 built in $(( $(date +%s) - t1 )) s."
echo "$STAMP_WANT" >"$DEST/.calibgraph-stamp"
echo "install_kinect_sdk: done. A live Kinect also needs USB 3 and access to it: as root, cp $DEST/90-kinect2.rules /etc/udev/rules.d/ (then replug), or run as root."
