#!/usr/bin/env bash
# Set up mi_loop on Debian 12 (run as root from anywhere; works on the repo it lives in).
#  1. system libraries: libLLVM >= 16 for Dr.Jit (Debian's LLVM 15 crashes: "Cannot select: ...
#     fminimum"), libatomic for Mitsuba, OpenGL/fontconfig libraries that pymeshlab links to,
#     libgomp for Numba's OpenMP threading layer (mi_loop._numba), and
#     Debian's chromium, the headless browser the report.html tests drive (through playwright,
#     which is told to use it and downloads no browser of its own);
#  2. a virtual environment .venv with `pip install -e '.[test]'`.
# Idempotent: each step is skipped when already done, so a second run takes about a second.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"

say() { echo "[setup] $*" >&2; }

# --- 1. Debian packages -------------------------------------------------------------------
packages=(libatomic1 libgl1 libopengl0 libfontconfig1 libgmp10 libgomp1 chromium)
python3 mi_loop/_llvm.py >/dev/null 2>&1 || packages+=(libllvm19)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
    if ! command -v apt-get >/dev/null; then
        say "missing ${missing[*]} and no apt-get: install them by hand"; exit 1
    fi
    say "installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
python3 mi_loop/_llvm.py >&2 || { say "no libLLVM >= 16 after install: run apt-get install libllvm19"; exit 1; }

# --- 2. virtual environment ---------------------------------------------------------------
if ! .venv/bin/python -c "import pip" >/dev/null 2>&1; then
    say "creating .venv"
    rm -rf .venv
    if ! python3 -m venv .venv >/dev/null 2>&1; then
        # Debian's own python3 ships venv without ensurepip until python3-venv is installed.
        say "installing python3-venv"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq python3-venv >/dev/null
        rm -rf .venv
        python3 -m venv .venv
    fi
fi

# Reinstall only when pyproject.toml changed since the last successful install.
stamp=.venv/.mi_loop-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -x .venv/bin/mi-loop ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    say "pip install -e '.[test]' (first time: a few minutes)"
    .venv/bin/python -m pip install -q --disable-pip-version-check -e '.[test]'
    echo "$want" > "$stamp"
fi
say "ready: .venv/bin/mi-loop, .venv/bin/python -m pytest"
