#!/usr/bin/env bash
# CUDA-only tests on the device machine: resume within tolerance (the hash grid's backward uses atomics) and
# anything else marked to skip without CUDA. Usage (repo root; carry .whl/ with pytest and its dependencies):
#   bash bench/gpu/cuda_checks.sh
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
python3 -m pytest -q -p no:cacheprovider test/core/training/test_trainer.py -k cuda -rs
