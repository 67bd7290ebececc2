#!/usr/bin/env bash
# The GPU pipeline run of issue #3/#4 on the device machine (Python 3.12, torch with CUDA, no registry).
# Usage (repo root, wheels for fast_hdbscan/hdbscan/mcap/lz4/zstandard carried in .whl/):
#   bash bench/gpu/run.sh VIEWS RESOLUTION [RUN_CONFIG.yaml]
# Writes the logs and result JSONs into $OUT (or ./gpu_out).
set -uo pipefail
views=${1:-300}; res=${2:-512}; cfg=${3:-}
out=${OUT:-gpu_out}; mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 TQDM_MININTERVAL=10
fnp() { python3 -m fruitnerfpp_ros.cli.main "$@"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$out/gpu.txt"
python3 -c 'import torch; print("torch", torch.__version__, torch.cuda.get_device_name())' | tee -a "$out/gpu.txt"
data=/tmp/apple_${views}_${res}
t0=$(date +%s)
fnp synth --fruit apple --views "$views" --resolution "$res" --device cuda --out "$data" --quiet >"$out/synth.log" 2>&1 \
  || { tail -20 "$out/synth.log"; exit 1; }
t1=$(date +%s)
echo "synth ${views} views ${res}px: $((t1 - t0)) s" | tee -a "$out/gpu.txt"
extra=(); [ -n "$cfg" ] && extra=(--config "$cfg")
timeout ${RUN_TIMEOUT:-420} python3 -m fruitnerfpp_ros.cli.main run "$data" --out /tmp/run --preset default --device cuda "${extra[@]}" 2>&1 | tr '\r' '\n' \
  | grep -v -E 'step/s|it/s|^\s*$' | tee "$out/run.log" | tail -30
t2=$(date +%s)
echo "run (train+export+count+eval): $((t2 - t1)) s" | tee -a "$out/gpu.txt"
for f in metrics.jsonl export.json counts.json eval.json train_summary.json; do [ -f /tmp/run/$f ] && cp /tmp/run/$f "$out/"; done
# Density-threshold sweep on the same fields (export + count + eval only).
for thr in ${SWEEP:-}; do
  fnp export /tmp/run --out /tmp/sweep_$thr/cloud.ply --density-threshold "$thr" --device cuda >/dev/null 2>&1
  fnp count /tmp/sweep_$thr/cloud.npz --out /tmp/sweep_$thr/counts.json >/dev/null 2>&1
  echo "density >= $thr: $(fnp eval /tmp/sweep_$thr/counts.json --gt "$data/gt_fruits.json" --json | python3 -c 'import json,sys; d=json.load(sys.stdin); print({k: d[k] for k in ("count","gt_count","precision","recall","f1")})')" | tee -a "$out/gpu.txt"
done
