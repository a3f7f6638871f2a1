#!/usr/bin/env bash
# opnet's device check in one call, on a GPU machine without a package registry:
#   1. install: opnet (editable, from this working tree) and the dependencies the machine's Python lacks, from carried
#      wheels (pip install --no-index --no-deps --find-links $WHEELS); the machine's own torch is kept (checked);
#   2. the import, and the device tests (tests/unit/test_device_side.py, test_inference.py, test_bench_infer.py) on CUDA;
#   3. scripts/bench_infer.py --device cuda: forward and end to end, batch 1 and 32, fp32 / bf16 / CUDA graph
#      -> latency.csv (device, network, batch, precision, forward_ms, end_to_end_ms, ...) and infer.csv;
#   4. scripts/bench_train.py: the training loop's images/s for experiment=paper against the network alone
#      -> train_throughput.csv;
#   5. the quickstart on existing data (train.py experiment=quickstart data=ipa ...) -> quickstart.csv (seconds, test AP).
# Without CUDA it says so and runs the same steps as a dry run with tiny sizes (tiny network, batches 1 and 2, a few
# steps, one epoch of a generated 3-cycle dataset), installing into a throwaway venv instead of the machine's Python.
#
# Usage (from the repository root):
#   scripts/gpu_check.sh                 # the check (or the dry run without CUDA)
#   scripts/gpu_check.sh prepare         # here, before carrying: download the missing wheels for CPython 3.12 into
#                                        # $WHEELS and pack $DATA into .carry/data.tar.xz (scripts/carry_dataset.py)
# Environment: PYTHON (python3), WHEELS (.whl), DATA (the quickstart dataset: an IPA folder or a carry_dataset.py
# archive; the dry run generates one when unset), OUT (the results folder: $OUT, else results/gpu, or
# outputs/gpu_check_dry for a dry run), BUDGET_S (the time budget of the whole call: default 480 s on a GPU, expected
# about 300 s on an H100; each step has its own limit (install 60, tests 150, latency 120, training throughput 120,
# quickstart 180 s) and one that would overrun the budget is cut to what is left of it). On the GPU machine run it as
# one command, with .whl and .carry beside the working tree and a time limit above BUDGET_S.
# Files written (at most 8, for $OUT): gpu_check.log, summary.md, latency.csv, infer.csv, train_throughput.csv,
# quickstart.csv, tests.log. The exit status is the number of failed steps.
set -uo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PY=${PYTHON:-python3}
WHEELS=${WHEELS:-.whl}
DATA=${DATA:-}
export PYTHONUNBUFFERED=1 PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}

if [ "${1:-}" = "prepare" ]; then
    # the packages opnet needs that a GPU machine's CPython 3.12 with torch, lightning, scikit-learn, scipy and
    # OpenCV lacks, at the versions of requirements.lock
    # (pytest and hypothesis for the tests); antlr4-python3-runtime has no wheel on the registry: built here
    mkdir -p "$WHEELS" .carry
    need="hydra-core omegaconf trimesh albumentations albucore pydantic pydantic-core annotated-types typing-inspection
          simsimd stringzilla pytest pluggy iniconfig hypothesis sortedcontainers attrs"
    pins=()
    for name in $need; do
        pin=$(grep -i "^${name}==" requirements.lock) || { echo "prepare: $name is not in requirements.lock"; exit 2; }
        pins+=("$pin")
    done
    $PY -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        --platform any -d "$WHEELS" "${pins[@]}" || exit 2
    $PY -m pip wheel -q --no-deps -w "$WHEELS" "$(grep -i '^antlr4-python3-runtime==' requirements.lock)" || exit 2
    if [ -n "$DATA" ]; then $PY scripts/carry_dataset.py pack "$DATA" .carry/data.tar.xz || exit 2; fi
    du -sh "$WHEELS" .carry
    echo "carry: $WHEELS .carry (add both to .git/info/exclude); run: DATA=.carry/data.tar.xz scripts/gpu_check.sh"
    exit 0
fi

if $PY -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)" 2>/dev/null; then
    MODE=gpu
    DEST=${OUT:-results/gpu}
    BUDGET_S=${BUDGET_S:-480}
else
    MODE=dry
    DEST=${OUT:-outputs/gpu_check_dry}
    BUDGET_S=${BUDGET_S:-900}
fi
mkdir -p "$DEST"
DEST=$(cd "$DEST" && pwd)
WORK=$(mktemp -d "${TMPDIR:-/tmp}/opnet_gpu_check.XXXXXX")
LOG=$DEST/gpu_check.log
SUMMARY=$DEST/summary.md
START=$(date +%s)
FAILED=0
: >"$LOG"
say() { echo "$*" | tee -a "$LOG"; }
elapsed() { echo $(($(date +%s) - START)); }

if [ "$MODE" = gpu ]; then
    say "gpu_check: CUDA found ($($PY -c 'import torch; print(torch.cuda.get_device_name())')): the full check, budget ${BUDGET_S} s"
    MODEL=paper BATCHES=1,32 REPEATS=10 STEPS=40 WARMUP=10 WORKERS=8
    TRAIN_EXTRA=(experiment=paper data.generate=null)
    QUICK=(experiment=quickstart trainer=gpu data.num_workers=8)
    ACCEL=gpu ARM=bf16+cl
else
    say "gpu_check: no CUDA device: a CPU dry run of the same steps with tiny sizes, budget ${BUDGET_S} s"
    MODEL=tiny BATCHES=1,2 REPEATS=2 STEPS=2 WARMUP=1 WORKERS=0
    TRAIN_EXTRA=(experiment=paper data.generate=null model=tiny data.batch_size=4 trainer=cpu)
    QUICK=(experiment=quickstart model=tiny trainer.max_epochs=1 data.batch_size=4 data.num_workers=0
           data.cache_workers=1 example_predictions=0)
    ACCEL=cpu ARM=fp32
fi
printf '# gpu_check (%s)\n\n| step | status | seconds |\n|---|---|---|\n' "$MODE" >"$SUMMARY"

# step NAME SECONDS COMMAND...: run with a time limit (cut to what is left of the budget), log, record in the summary
step() {
    local name=$1 limit=$2
    shift 2
    local left=$((BUDGET_S - $(elapsed)))
    if [ "$left" -lt 10 ]; then
        say "== $name: skipped, the budget is spent"
        echo "| $name | skipped (budget) | 0 |" >>"$SUMMARY"
        FAILED=$((FAILED + 1))
        return 1
    fi
    [ "$limit" -gt "$left" ] && limit=$left
    say "== $name (at most ${limit} s, ${left} s of the budget left): $*"
    local t0 rc
    t0=$(date +%s)
    if declare -F "$1" >/dev/null; then  # a function of this script: in a bash of its own, under the limit
        timeout --kill-after=10 "$limit" bash -c "$(declare -f "$1"); \"\$@\"" _ "$@" >>"$LOG" 2>&1
    else
        timeout --kill-after=10 "$limit" "$@" >>"$LOG" 2>&1
    fi
    rc=$?
    local took=$(($(date +%s) - t0))
    if [ $rc -eq 0 ]; then
        say "   $name: ok in ${took} s"
        echo "| $name | ok | $took |" >>"$SUMMARY"
    else
        [ $rc -eq 124 ] && rc="$rc (time limit)"
        say "   $name: FAILED (exit $rc) after ${took} s; the log's end:"
        tail -n 15 "$LOG" | sed 's/^/   | /'
        echo "| $name | failed, exit $rc | $took |" >>"$SUMMARY"
        FAILED=$((FAILED + 1))
    fi
    return 0
}

# ---- 1. install --------------------------------------------------------------------------------------------------
install() {
    local py=$1
    local before after missing
    before=$($py -c "import torch; print(torch.__version__, torch.__file__)")
    # the carried wheels whose distributions this Python lacks (a present one is kept: no numpy or torch replaced)
    missing=$($py - "$WHEELS" <<'EOF'
import sys
from importlib import metadata
from pathlib import Path

folder = Path(sys.argv[1])
for wheel in sorted(folder.glob("*.whl")) if folder.is_dir() else []:
    name = wheel.name.split("-")[0]
    if name.lower() in ("torch", "opnet"):
        continue  # never the machine's torch; opnet comes from the working tree
    try:
        metadata.version(name)
    except metadata.PackageNotFoundError:
        print(wheel)
EOF
)
    if [ -n "$missing" ]; then
        echo "installing from $WHEELS: $(echo "$missing" | xargs -n1 basename | tr '\n' ' ')"
        # shellcheck disable=SC2086
        $py -m pip install -q --no-index --no-deps --find-links "$WHEELS" $missing || return 1
    else
        echo "no carried wheel needed (every dependency is installed)"
    fi
    # opnet itself, editable: conf/ and the scripts stay where they are
    $py -m pip install -q --no-index --no-deps --no-build-isolation -e . || return 1
    after=$($py -c "import torch; print(torch.__version__, torch.__file__)")
    echo "torch before: $before"
    echo "torch after : $after"
    [ "$before" = "$after" ] || { echo "the install replaced torch"; return 1; }
}

export WHEELS
if [ "$MODE" = gpu ]; then
    step install 60 install "$PY"
else  # a throwaway venv over this machine's packages: the same commands, this machine's Python untouched
    $PY -m venv --system-site-packages --without-pip "$WORK/venv" >>"$LOG" 2>&1  # pip and setuptools: this Python's
    PY=$WORK/venv/bin/python
    step install 120 install "$PY"
fi

# ---- 2. import and tests -----------------------------------------------------------------------------------------
step import 60 "$PY" -c "
import torch, opnet, opnet.inference, opnet.data.preprocess_torch, opnet.parameterizations.averaging_torch
print('opnet from', opnet.__file__, '| torch', torch.__version__, '| cuda', torch.cuda.is_available(),
      torch.cuda.get_device_name() if torch.cuda.is_available() else '')"

# the data: a carried archive is unpacked; the dry run generates a small dataset (and packs and unpacks it, the
# carrying path) when none is given
if [ -z "$DATA" ] && [ "$MODE" = dry ]; then
    step generate 300 "$PY" generate.py object=shaft cycles=3 drops=4 scene.resolution=128 previews=0 progress=false \
        "out=$WORK/generated" hydra.run.dir="$WORK/hydra_generate"
    step pack 60 "$PY" scripts/carry_dataset.py pack "$WORK/generated" "$WORK/data.tar.xz"
    DATA=$WORK/data.tar.xz
fi
if [ -n "$DATA" ] && [ -f "$DATA" ]; then
    step unpack 120 "$PY" scripts/carry_dataset.py unpack "$DATA" "$WORK/data"
    DATA=$WORK/data
fi
if [ -z "$DATA" ] || [ ! -d "$DATA" ]; then
    say "no dataset (DATA=${DATA:-unset}): the training and quickstart steps are skipped"
fi

export OPNET_PILE=${DATA:-}  # the device tests read rendered frames from it instead of rendering their own
run_tests() {  # the whole pytest output in tests.log, its end in the main log
    "$1" -m pytest -q -p no:cacheprovider tests/unit/test_device_side.py tests/unit/test_inference.py \
        tests/unit/test_bench_infer.py -k "not shared" >"$2" 2>&1
    local rc=$?
    tail -n 12 "$2"
    return $rc
}
step tests 150 run_tests "$PY" "$DEST/tests.log"

# ---- 3. latency --------------------------------------------------------------------------------------------------
DEVICE=cpu
[ "$MODE" = gpu ] && DEVICE=cuda
step latency 120 "$PY" scripts/bench_infer.py --device "$DEVICE" --model "$MODEL" --batches "$BATCHES" \
    --repeats "$REPEATS" --parameterizations "" --no-onnx --out "$DEST/infer.csv" --latency-out "$DEST/latency.csv"

# ---- 4. training throughput and 5. the quickstart ---------------------------------------------------------------
if [ -n "$DATA" ] && [ -d "$DATA" ]; then
    step train_throughput 120 "$PY" scripts/bench_train.py --data "$DATA" --accelerator "$ACCEL" --arms "$ARM" \
        --workers "$WORKERS" --steps "$STEPS" --warmup "$WARMUP" --network-alone --extra "${TRAIN_EXTRA[@]}" \
        --throughput-out "$DEST/train_throughput.csv"
    RUN=$WORK/quickstart
    t0=$(date +%s)
    step quickstart 180 "$PY" train.py "${QUICK[@]}" data=ipa "data.root=$DATA" data.generate=null \
        hydra.run.dir="$RUN"
    took=$(($(date +%s) - t0))
    "$PY" - "$RUN" "$took" "$DEST/quickstart.csv" "$MODE" >>"$LOG" 2>&1 <<'EOF'
import json, sys
from pathlib import Path

run, took, out, mode = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]), sys.argv[4]
summary = run / "test" / "summary.json"
result = json.loads(summary.read_text()) if summary.is_file() else {}
out.write_text(f"mode,seconds,test_ap,test_scenes\n{mode},{took},{result.get('ap', '')},{result.get('scenes', '')}\n")
print(f"quickstart: {took} s, test AP {result.get('ap')} on {result.get('scenes')} scenes")
EOF
fi

say "== done in $(elapsed) s of ${BUDGET_S}, ${FAILED} failed step(s); results in $DEST"
ls -1 "$DEST" | tee -a "$LOG"
cat "$SUMMARY"
rm -rf "$WORK"
exit "$FAILED"
