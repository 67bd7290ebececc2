#!/usr/bin/env bash
# Issue #11's `gpu` suite on the device machine within one 10-minute call, with the idle CPU cores put to work on
# the fallback-mask `cpu` scenes at the same time (pinned apart, so the GPU scenes' launch threads are not starved).
# Usage (repo root; cp312 wheels of fast_hdbscan, hdbscan, mcap, rosbags and their needs carried in .whl/):
#   GPU_SCENES=apple_paper_283,peach_paper_152 GPU_JOBS=2 [GPU2_SCENES=apple_paper_283 GPU2_PRESET=cpu] \
#   [CPU_SCENES=apple_hemi_40,...] DEADLINE_S=520 bash bench/gpu/suite.sh
# Everything small (tables, JSON, pictures, logs) comes back as $OUT/suite.tgz; scenes cut by the deadline keep the
# stage times their logs reached. Runs locally too (PY=.venv/bin/python SKIP_WHEELS=1 GPU_DEVICE=cpu ...).
set -uo pipefail
out=${OUT:-gpu_out}; mkdir -p "$out"
py=${PY:-python3}
gpu_scenes=${GPU_SCENES:-apple_paper_283,peach_paper_152}
gpu_jobs=${GPU_JOBS:-2}
gpu_suite=${GPU_SUITE:-gpu}
gpu_device=${GPU_DEVICE:-cuda}
gpu_cores=${GPU_CORES:-0-5}
cpu_scenes=${CPU_SCENES:-}
cpu_jobs=${CPU_JOBS:-7}
cpu_cores=${CPU_CORES:-6-15}
deadline=${DEADLINE_S:-530}
extra=(); [ -n "${GPU_CONFIG:-}" ] && extra=(--config "$GPU_CONFIG")
work=${WORK:-/tmp/suite}; rm -rf "$work"; mkdir -p "$work"
if [ -z "${SKIP_WHEELS:-}" ]; then
  $py -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
fi
export PYTHONUNBUFFERED=1 TQDM_MININTERVAL=30
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1
  $py -c 'import torch; print("torch", torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name())'
  nproc; git log -1 --format='commit %h %s' 2>/dev/null; } > "$work/machine.txt" 2>&1
start=$(date +%s)
# fast_hdbscan's numba kernels compiled once into the disk cache while the scenes train (they cluster minutes later).
taskset -c "$cpu_cores" $py -c 'from fruitnerfpp_ros.core.clustering.hdbscan_cluster import warm_up
print(f"numba warm-up {warm_up():.0f} s")' > "$work/warm_up.txt" 2>&1 &
timeout "$deadline" taskset -c "$gpu_cores" $py -m fruitnerfpp_ros.cli.main bench accuracy --suite "$gpu_suite" \
  --scenes "$gpu_scenes" --jobs "$gpu_jobs" --out "$work/g" --device "$gpu_device" "${extra[@]}" \
  > "$work/gpu_suite.log" 2>&1 &
gpu_pid=$!
if [ -n "${GPU2_SCENES:-}" ]; then  # a second preset on the same GPU, for comparison
  timeout "$deadline" taskset -c "$gpu_cores" $py -m fruitnerfpp_ros.cli.main bench accuracy --suite "$gpu_suite" \
    --scenes "$GPU2_SCENES" --preset "${GPU2_PRESET:-cpu}" --jobs 1 --out "$work/g2" --device "$gpu_device" \
    > "$work/gpu2_suite.log" 2>&1 &
fi
if [ -n "$cpu_scenes" ]; then
  timeout "$deadline" taskset -c "$cpu_cores" $py -m fruitnerfpp_ros.cli.main bench accuracy --suite cpu \
    --masks fallback --scenes "$cpu_scenes" --jobs "$cpu_jobs" --out "$work/cf" --device cpu \
    > "$work/cpu_suite.log" 2>&1 &
fi
while kill -0 "$gpu_pid" 2>/dev/null; do
  sleep 20
  { echo "t=$(( $(date +%s) - start )) s"; nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader; } \
    >> "$work/gpu_util.txt" 2>&1
done
wait
echo "gpu suite + cpu scenes: $(( $(date +%s) - start )) s" | tee -a "$work/machine.txt"
# each scene's log without its progress bars (the end of it, which a scene cut by the deadline reached)
for s in "$work"/g/*/ "$work"/g2/*/ "$work"/cf/*/; do
  [ -f "$s/scene.log" ] && tr '\r' '\n' < "$s/scene.log" | grep -v '%|' | tail -c 20000 > "$s/scene_tail.log"
done
(cd "$work" && tar czf "$out/suite.tgz" --exclude='*/data' --exclude=checkpoints --exclude=keyframes --exclude=bag \
  --exclude='*.npz' --exclude='*.ply' --exclude='*/scene.log' --exclude='*.mcap' --exclude='*.db3' .)
ls -la "$out"; cat "$work/machine.txt"; tail -5 "$work/gpu_util.txt" 2>/dev/null
cat "$work/warm_up.txt"
for f in "$work"/g/accuracy.md "$work"/g2/accuracy.md "$work"/cf/accuracy.md; do [ -f "$f" ] && grep -v "^$" "$f" | head -24; done
tail -20 "$work/gpu_suite.log"
