#!/usr/bin/env bash
# The GPU check of issues 33 and 52 in one run on a lent GPU machine (see ../shared/tools/gpu-wheels.sh
# and docs/imaging.md, "The GPU path" and "Current figures"): the real-GPU tests, then bench_gpu.py (with a profile of
# one pass), bench_gpu_synthesis.py and bench_threads.py, each bounded in time, results and
# logs under $OUT (at most 8 files come back).
#   device run, carry [".whl"]:  bash benchmarks/gpu_check.sh
set -u
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target .site .whl/*.whl && export PYTHONPATH=$PWD:$PWD/.site || exit 1
export PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/gpu_check}; mkdir -p "$OUT"
T_TESTS=${T_TESTS:-330} T_GPU=${T_GPU:-300} T_SYN=${T_SYN:-80} T_THR=${T_THR:-80}
STAGES=${STAGES:-"tests bench_gpu bench_gpu_synthesis bench_threads"}
{
  date -u; nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv
  lscpu | grep -E '^(Model name|CPU\(s\)|Thread|Core)'
  echo "avx512: $(grep -o -w 'avx512[a-z0-9_]*' /proc/cpuinfo | sort -u | tr '\n' ' ')"
  python3 -c "import sys, numpy, numba, numba_cuda; from numba import cuda; \
print(sys.version.split()[0], 'numpy', numpy.__version__, 'numba', numba.__version__, \
'numba-cuda', numba_cuda.__version__, 'gpu', cuda.is_available())"
} > "$OUT/tests.log" 2>&1
cat "$OUT/tests.log"          # (the machine heads the tests' log: 8 files come back at most)
stage() { local name=$1 limit=$2; shift 2; local t0=$SECONDS
  timeout "$limit" "$@" >> "$OUT/$name.log" 2>&1; local rc=$?
  echo "== $name rc=$rc $((SECONDS - t0)) s"; tail -n 25 "$OUT/$name.log"; }
# pytest-timeout (on the GPU machine's image): a stuck test fails with its stack and the rest
# run; the real-GPU tests first, in their own pytest run, so that a slow simulator test
# can't take their time or their report (pytest prints failures at the end of a run)
# (the tests named real_gpu are those that need the device; the rest of these files run
# the kernels under numba's CUDA simulator, as on every machine, and run only when
# SIM_TESTS=1: the device time is better spent on the benchmarks)
# (a fresh machine compiles every kernel: the 18 CPU and 18 GPU kernels of
# test_real_gpu_matches_direct_sum_and_cpu took over 150 s beside the other tests' compiles)
T_EACH=${T_EACH:-300}
to=""; python3 -c "import pytest_timeout" 2>/dev/null && to="-p timeout --timeout=$T_EACH"
# (GPU_TESTS=...: a subset, where device time is short)
ALL_GPU_TESTS="tests/test_gpu_float32.py tests/test_gpu_kernel.py tests/sim/test_gpu_synthesis.py"
ALL_GPU_TESTS="$ALL_GPU_TESTS tests/test_gpu_imager.py tests/test_cone_edges.py tests/test_gpu_batch.py"
ALL_GPU_TESTS="$ALL_GPU_TESTS tests/test_gpu_conditioning.py"
GPU_TESTS=${GPU_TESTS:-$ALL_GPU_TESTS}
SIM_TESTS=${SIM_TESTS:-0}
for st in $STAGES; do case $st in
  tests) stage tests "$T_TESTS" bash -c "python3 -m pytest -q -p no:cacheprovider -rfEs \
    --tb=short --durations=8 $to --junitxml=$OUT/tests.xml -k real_gpu $GPU_TESTS; r=\$?; if [ $SIM_TESTS = 1 ]; then \
    python3 -m pytest -q -p no:cacheprovider -rfEs --tb=short --durations=8 $to \
    -k 'not real_gpu' $GPU_TESTS || r=1; fi; exit \$r" ;;
  bench_gpu) stage bench_gpu "$T_GPU" python3 benchmarks/bench_gpu.py --repeat 2 --profile \
    --out "$OUT/bench_gpu.json" ;;
  bench_gpu_synthesis) stage bench_gpu_synthesis "$T_SYN" python3 \
    benchmarks/bench_gpu_synthesis.py --pings 3 --out "$OUT/bench_gpu_synthesis.json" ;;
  bench_threads) stage bench_threads "$T_THR" python3 benchmarks/bench_threads.py --pings 20 \
    --reps 1 --out "$OUT/bench_threads.json" ;;
esac; done
