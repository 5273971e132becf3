#!/usr/bin/env bash
# The wheels scripts/gpu-check.sh needs on a GPU machine that reaches no package index: the runtime
# dependencies its image lacks (it has torch, numpy, matplotlib, tqdm, pytest, hypothesis), for its
# Python 3.12 on x86-64, downloaded here into .whl/ (git-ignored through .git/info/exclude).
#
#   scripts/gpu-wheels.sh            # then carry .whl to the GPU machine with the working tree
set -euo pipefail
cd "$(dirname "$0")/.."
grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
    gymnasium pettingzoo farama-notifications jsonschema jsonschema-specifications referencing rpds-py \
    mcap zstandard
ls .whl
