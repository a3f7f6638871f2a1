#!/usr/bin/env bash
# The lock file and its check on newer Pythons.
#
#   scripts/dev/lock.sh            # re-make requirements.lock from pyproject.toml (keeps locked versions where they still fit)
#   scripts/dev/lock.sh --check    # every locked package resolves for CPython 3.12 and 3.13 on manylinux x86_64 as a
#                              # binary wheel, except the pure-Python source packages named in SOURCE_ONLY
#
# requirements.lock is universal (markers per Python version and platform): CI and the README install
# with `pip install -c requirements.lock -e ".[dev]"`. It needs uv (pip install uv) and the package index.
set -euo pipefail
cd "$(dirname "$0")/../.."
# pure-Python packages published as source only (no compiler needed): omegaconf's parser runtime, pyrender's OpenGL
SOURCE_ONLY=(antlr4-python3-runtime pyopengl)

if [[ "${1:-}" != "--check" ]]; then
    uv pip compile pyproject.toml --extra dev --universal --python-version 3.11 -o requirements.lock --no-header
    exit 0
fi
names=$(grep -E '^[A-Za-z0-9_.-]+==' requirements.lock | cut -d= -f1 | tr 'A-Z_' 'a-z-' | sort -u)
args=()
for n in $names; do
    [[ " ${SOURCE_ONLY[*]} " == *" $n "* ]] || args+=(--only-binary "$n")
done
for v in ${PYTHONS:-3.12 3.13}; do
    out=$(mktemp)
    uv pip compile requirements.lock --python-version "$v" --python-platform x86_64-manylinux_2_28 --no-deps \
        "${args[@]}" --no-header -q -o "$out"
    echo "CPython $v: $(grep -c '==' "$out") locked packages resolve, binary wheels for all but ${SOURCE_ONLY[*]};" \
        "$(grep -E '^(torch|mujoco|coacd|pybullet)==' "$out" | cut -d' ' -f1 | tr '\n' ' ')"
    rm -f "$out"
done
