#!/usr/bin/env bash
# Prepare the files a CUDA machine without network needs to run scripts/gpu_check.sh.
#
# Run here, with network. Downloads into .gpu/ (git-ignored):
#   .gpu/warp/warp_lang-1.19.0-py3-none-manylinux_2_28_x86_64.whl.part-aa, -ab, -ac
#       the Warp wheel (149 MB) in parts of $PART_SIZE, so each part travels in one call. Each call
#       carries at most 64 MiB with the working tree (~3 MB): 57M parts leave ~4 MB of room in every
#       call (60M parts leave ~1 MB in the first two); the last call also carries the wheels below;
#   .gpu/warp/SHA256SUMS, PARTS  the wheel's checksum (checked after joining) and its parts in order;
#   .gpu/wheels/*.whl      the other packages the device run needs that its image lacks
#       (trimesh for mesh I/O, usd-core for the design bench's shipped scenes).
# The device image already holds python3 3.12, numpy and pytest (and pytest's own dependencies).
#
#   bash scripts/gpu_prepare.sh            # download, split, print the transfer plan
#   PART_SIZE=60M bash scripts/gpu_prepare.sh
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-$( [ -x .venv/bin/python ] && echo .venv/bin/python || echo python3 )}
PART_SIZE=${PART_SIZE:-57M}
WARP_VERSION=1.19.0
WARP_WHEEL=warp_lang-${WARP_VERSION}-py3-none-manylinux_2_28_x86_64.whl
EXTRA=("trimesh==5.2.0" "usd-core==26.11")
PLATFORM=(--python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64
          --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)

mkdir -p .gpu/download .gpu/warp .gpu/wheels
grep -qxF '/.gpu/' .gitignore || { echo "add /.gpu/ to .gitignore first" >&2; exit 1; }

if [ ! -f ".gpu/download/$WARP_WHEEL" ]; then
  "$PYTHON" -m pip download --no-deps --only-binary=:all: "${PLATFORM[@]}" -d .gpu/download "warp-lang==$WARP_VERSION"
fi
[ -f ".gpu/download/$WARP_WHEEL" ] || { echo "pip saved no $WARP_WHEEL in .gpu/download" >&2; exit 1; }
rm -f .gpu/wheels/*.whl
"$PYTHON" -m pip download --no-deps --only-binary=:all: "${PLATFORM[@]}" -d .gpu/wheels "${EXTRA[@]}"

rm -f .gpu/warp/*
(cd .gpu/download && sha256sum "$WARP_WHEEL") > .gpu/warp/SHA256SUMS
split -b "$PART_SIZE" -a 2 ".gpu/download/$WARP_WHEEL" ".gpu/warp/$WARP_WHEEL.part-"
(cd .gpu/warp && ls "$WARP_WHEEL".part-* > PARTS)

# What travels in each call: the working tree (tracked + untracked-not-ignored files) plus the carry.
tree_bytes=$(git ls-files -co --exclude-standard -z | xargs -0 stat -c %s 2>/dev/null | awk '{s+=$1} END {print s+0}')
limit=$((64 * 1024 * 1024))
parts=(.gpu/warp/*.part-*)
echo "working tree: $tree_bytes bytes; per-call limit $limit bytes"
n=${#parts[@]}
for i in "${!parts[@]}"; do
  p=${parts[$i]}
  carry=("$p")
  if [ "$i" -eq $((n - 1)) ]; then carry+=(.gpu/warp/SHA256SUMS .gpu/warp/PARTS .gpu/wheels); fi
  bytes=$(du -cb "${carry[@]}" | tail -1 | cut -f1)
  total=$((bytes + tree_bytes))
  ok=fits; [ "$total" -le "$limit" ] || ok="TOO LARGE: lower PART_SIZE"
  echo "call $((i + 1))/$n carry: ${carry[*]}  ($total bytes with the tree: $ok)"
done
