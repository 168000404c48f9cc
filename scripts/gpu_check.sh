#!/usr/bin/env bash
# The device check in one command (docs/gpu.md): on a CUDA machine without network, install Warp and
# the other wheels from the files carried beside the repository (scripts/gpu_prepare.sh made them),
# stage the project where Python finds it, run the CUDA tests, the batched-worlds step bench and the
# design bench, and write DIR/gpu_check.json and DIR/gpu_check.md (the path is printed at the end).
#
#   bash scripts/gpu_check.sh [--device cuda:0|cpu] [--quick | --tiny] [--out DIR] [--skip-tests]
#                             [--from DIR]...
#
# Install: skipped when `python3 -c "import warp"` works. Otherwise the Warp wheel is joined from its
# parts (.gpu/warp/*.part-*, or any --from folder such as /tmp/gpu-carry where earlier calls left
# parts), checked against .gpu/warp/SHA256SUMS and installed with the wheels in .gpu/wheels (or a
# --from folder) by `pip install --no-index --no-deps --target $GPU_CHECK_SITE`.
# Staging: warp_shape/, kernels/ (as warp_shape/kernels), benchmarks/ (as warp_shape/benchmarks) and
# scenes/ (as warp_shape/scenes) are copied into $GPU_CHECK_SITE, mirroring pyproject's package-dir
# mapping, so no build step is needed; Python runs with -P so the source tree never shadows it.
# Plans: full (default, under 8 minutes on an H200), --quick (under 3), --tiny (a CPU dry run).
# Exit status: 0 when every phase ran and the tests passed, 1 otherwise, 2 when the install failed.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-python3}
SITE=${GPU_CHECK_SITE:-/tmp/warp_shape_site}
WARP_WHEEL=warp_lang-1.19.0-py3-none-manylinux_2_28_x86_64.whl
DEVICE=cuda:0
OUT_DIR=$ROOT/out/gpu_check
DRIVER_ARGS=()
FROM=("$ROOT/.gpu/warp" "$ROOT/.gpu/wheels")

while [ $# -gt 0 ]; do
  case "$1" in
    --device) DEVICE=$2; shift 2 ;;
    --out) OUT_DIR=$2; shift 2 ;;
    --quick|--tiny|--skip-tests) DRIVER_ARGS+=("$1"); shift ;;
    --from) FROM+=("$2"); shift 2 ;;
    -h|--help) sed -n '2,21p' "$0"; exit 0 ;;
    *) echo "gpu_check: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
mkdir -p "$OUT_DIR"
OUT_DIR=$(cd "$OUT_DIR" && pwd)

first_of() {  # first existing file named $1 in the --from folders
  local d
  for d in "${FROM[@]}"; do [ -f "$d/$1" ] && { echo "$d/$1"; return 0; }; done
  return 1
}

install_wheels() {
  local sums list name part joined parts=() wheels=()
  sums=$(first_of SHA256SUMS) && list=$(first_of PARTS) ||
    { echo "gpu_check: no SHA256SUMS and PARTS in ${FROM[*]}: run scripts/gpu_prepare.sh, carry .gpu/warp" >&2; return 1; }
  mapfile -t parts < "$list"
  mkdir -p /tmp/gpu-join
  joined=/tmp/gpu-join/$WARP_WHEEL
  : > "$joined"
  for name in "${parts[@]}"; do
    part=$(first_of "$name") || { echo "gpu_check: part $name missing (looked in ${FROM[*]}); carry it again" >&2; return 1; }
    cat "$part" >> "$joined"
  done
  (cd /tmp/gpu-join && sha256sum -c --quiet "$sums") || { echo "gpu_check: joined wheel fails its checksum" >&2; return 1; }
  for d in "${FROM[@]}"; do
    for f in "$d"/*.whl; do [ -f "$f" ] && wheels+=("$f"); done
  done
  echo "installing $WARP_WHEEL ${wheels[*]##*/} into $SITE"
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" \
    "$joined" "${wheels[@]}"
}

stage_project() {  # the installed layout (pyproject package-dir mapping), without a build
  mkdir -p "$SITE"
  rm -rf "$SITE/warp_shape"
  cp -r "$ROOT/warp_shape" "$SITE/warp_shape"
  cp -r "$ROOT/kernels" "$SITE/warp_shape/kernels"
  cp -r "$ROOT/benchmarks" "$SITE/warp_shape/benchmarks"
  cp -r "$ROOT/scenes" "$SITE/warp_shape/scenes"
  find "$SITE/warp_shape" -name __pycache__ -prune -exec rm -rf {} +
}

t0=$(date +%s)
export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}"
if "$PY" -P -c "import warp" 2>/dev/null; then
  echo "warp importable: install skipped"
else
  install_wheels || exit 2
fi
stage_project
command -v nvidia-smi >/dev/null && nvidia-smi -L || true
echo "install and staging: $(( $(date +%s) - t0 )) s"

set +e
PYTHONUNBUFFERED=1 "$PY" -P -m warp_shape.benchmarks.gpu_check --device "$DEVICE" --out "$OUT_DIR" --root "$ROOT" \
  ${DRIVER_ARGS[@]+"${DRIVER_ARGS[@]}"}
rc=$?
set -e
echo "whole check: $(( $(date +%s) - t0 )) s, exit status $rc"
echo "results: $OUT_DIR/gpu_check.json $OUT_DIR/gpu_check.md"
exit $rc
