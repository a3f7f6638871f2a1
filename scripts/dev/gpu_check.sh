#!/usr/bin/env bash
# opnet's device check in one call, on a GPU machine without a package registry:
#   1. install: the dependencies the machine's Python lacks, from carried wheels (pip install --no-index --no-deps;
#      a distribution that is importable already is skipped, so wheels installed beforehand with --target and
#      PYTHONPATH count), and opnet itself: nothing when it imports from this tree's src/ already (PYTHONPATH), else
#      editable; the machine's own torch is kept (checked);
#   2. the import, and the device tests (tests/unit/test_device_side.py, test_inference.py, test_bench_infer.py) on CUDA;
#   3. scripts/bench/bench_infer.py --device cuda: forward and end to end, batch 1 and 32, fp32 / bf16 / CUDA graph
#      -> latency.csv (device, network, batch, precision, forward_ms, end_to_end_ms, ...) and infer.csv;
#   4. scripts/bench/bench_train.py: the training loop's images/s for experiment=paper against the network alone
#      -> train_throughput.csv;
#   5. the quickstart on existing data (train.py experiment=quickstart data=ipa ...) -> quickstart.csv (seconds, AP);
#   6. table1, when a bunny dataset is there (BUNNY): the paper's Table I arms vanilla, eve, ap and si for the bunny
#      with the paper's network and input (train.py experiment=paper object=bunny parameterization=P seed=0 data=ipa
#      ...), all four at once on the one GPU, each for TABLE1_STEPS steps (trainer.max_time stops them sooner when the
#      budget is short) and scored on its test split -> table1.csv (parameterization, steps, seconds, test_ap, ...).
# Without CUDA it says so and runs the same steps as a dry run with tiny sizes (tiny network, batches 1 and 2, a few
# steps, one short epoch; a 3-cycle dataset generated when DATA is unset), installing into a throwaway venv instead
# of the machine's Python. With DATA given, that venv hides the generator's packages (mujoco, coacd, pyrender,
# PyOpenGL, pybullet), which the GPU machine lacks: the dry run then shows that no step imports them.
#
# Usage (from the repository root):
#   scripts/dev/gpu_check.sh                 # the check (or the dry run without CUDA)
#   scripts/dev/gpu_check.sh prepare         # here, before carrying: download the missing wheels for CPython 3.12 into
#                                        # $WHEELS (antlr4-python3-runtime built), generate the quickstart's dataset
#                                        # and the bunny's where absent, pack and verify both into .carry/
#                                        # (scripts/dev/carry_dataset.py), and print what the call will carry
# Environment: PYTHON (python3), WHEELS (.whl), DATA (the quickstart dataset: an IPA folder or a carry_dataset.py
# archive; the dry run generates one when unset; prepare: the folder to pack, default the quickstart's own
# outputs/data/shaft_c150_d10_s0_r256), BUNNY (the table1 dataset, folder or archive, default .carry/bunny.tar.xz when
# it exists, BUNNY=none: no table1; prepare: the folder to pack, default outputs/data/bunny_c16_d20_s0_r256),
# BUNNY_CYCLES (prepare: 16, the cycles of 20-part bunny piles generated; 0: no bunny), PY312 (prepare: a CPython 3.12
# to check that the wheels install offline), OUT (the results folder: $OUT, else results/gpu, or outputs/gpu_check_dry
# for a dry run), BUDGET_S (the time budget of the whole call: default 480 s on a GPU; each step has its own limit
# (install 60, tests 150, latency 120, training throughput 120, quickstart 180, table1 TABLE1_S = 180 s) and one that
# would overrun the budget is cut to what is left of it; table1 is skipped with less than 100 s left), TABLE1_STEPS
# (each arm's optimizer steps: 400 on a GPU).
# On the GPU machine run it as one command, with .whl and .carry beside the working tree and a time limit above
# BUDGET_S.
#   7. arms, when ARMS_DATA is given: Table I of the object ARMS_OBJECT at the experiment=table1 budget (every
#      parameterization x 3 seeds, 1350 steps each, ARMS_JOBS = 18 at once on the one GPU, each tuned on its validation
#      split; scripts/experiments/table1/table1.py --jobs) -> arms_<object>.tar.gz, which `scripts/experiments/table1/table1.py --collect --runs-dir <the
#      unpacked folder> --objects <object>` turns into a table here.
#   8. budget, when CELL_DATA is given: experiment=cell at CELL_MULTIPLES (1 2 4) times its steps, all at once
#      (scripts/experiments/cells/cells.py --stage budget), stopped within CELL_S (480 s) -> budget_x<m>_<name>.ckpt
#      (each budget's best) and budget.tar.gz (learning curves, configs, consoles), which `cells.py --stage budget-report --collect <dir>`
#      scores here (results/cells/budget.md). CELL_DATA: the cell's training piles packed by `carry_dataset.py
#      pack-cache` as <dataset>.tar.xz; CELL_SHARED: the reference-data folder with the cell's camera and mesh.
# ONLY="install unpack arms" (step names, a prefix before "_" included) runs just those steps.
# Files written (at most 8, for $OUT): gpu_check.log (the tests' output included), summary.md, latency.csv,
# infer.csv, train_throughput.csv, quickstart.csv, table1.csv. The exit status is the number of failed steps.
set -uo pipefail
cd "$(dirname "$0")/../.." || exit 2
ROOT=$(pwd)
PY=${PYTHON:-python3}
WHEELS=${WHEELS:-.whl}
DATA=${DATA:-}
BUNNY=${BUNNY:-}
export PYTHONUNBUFFERED=1 PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}

if [ "${1:-}" = "prepare" ]; then
    # The packages that train.py, eval, the tests and the benchmarks import and the GPU machine's CPython 3.12 lacks
    # (it has torch, lightning, torchmetrics, numpy, scipy, scikit-learn, OpenCV, matplotlib, tensorboard, pyyaml,
    # packaging, typing-extensions, pytest, hypothesis, as that machine listed them), at the versions of
    # requirements.lock (rtree: the r-tree behind trimesh's spatial queries, which the AP parameterization uses). The
    # generator's (mujoco, coacd, pyrender, PyOpenGL) stay here: nothing is generated there.
    # antlr4-python3-runtime has no wheel on the registry: built here (pure Python).
    set -e
    mkdir -p "$WHEELS" .carry
    for line in /.whl/ /.carry/; do  # both stay out of git and travel through the call's carry
        grep -qxF "$line" .git/info/exclude 2>/dev/null || echo "$line" >>.git/info/exclude
    done
    need="hydra-core omegaconf trimesh albumentations albucore pydantic pydantic-core annotated-types
          typing-inspection simsimd stringzilla rtree"
    pins=()
    for name in $need; do
        pin=$(grep -i "^${name}==" requirements.lock) || { echo "prepare: $name is not in requirements.lock"; exit 2; }
        pins+=("$pin")
    done
    $PY -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
        --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any -d "$WHEELS" "${pins[@]}"
    antlr=$(grep -i '^antlr4-python3-runtime==' requirements.lock)
    if [ ! -f "$WHEELS/antlr4_python3_runtime-${antlr#*==}-py3-none-any.whl" ]; then
        $PY -m pip wheel -q --no-deps -w "$WHEELS" "$antlr"
    fi
    if [ -n "${PY312:-}" ]; then  # the wheels install offline into a bare CPython 3.12 (pip checks the tags), and
        # those that need nothing the machine has import (pydantic_core needs typing_extensions, hydra pyyaml)
        site=$(mktemp -d)
        "$PY312" -m pip install -q --no-index --no-deps --no-compile --target "$site" "$WHEELS"/*.whl
        PYTHONPATH=$site "$PY312" -c "import antlr4, simsimd, stringzilla; print('CPython 3.12: the wheels install')"
        rm -rf "$site"
    fi
    # The quickstart's dataset as experiment=quickstart generates it (shaft, 150 cycles of 10 drops, 256 x 256,
    # seed 0) and the table1 arms' bunny: experiment=table1's 20-part piles at 256 x 256, seed 0, but BUNNY_CYCLES
    # cycles (its 60 pack to 32 MiB, more than the 64 MiB of a call leave beside the tree, wheels and quickstart).
    generate() {  # generate OUT ARGS...: generate.py completes OUT (a finished dataset is left as it is)
        local out=$1
        shift
        $PY generate.py "$@" workers=2 seed=0 scene.resolution=256 progress=false "out=$out" \
            hydra.run.dir="$(mktemp -d)"
    }
    if [ -z "$DATA" ]; then
        DATA=outputs/data/shaft_c150_d10_s0_r256
        generate "$DATA" object=shaft cycles=150 drops=10
    fi
    $PY scripts/dev/carry_dataset.py pack "$DATA" .carry/data.tar.xz
    $PY scripts/dev/carry_dataset.py verify "$DATA" .carry/data.tar.xz
    cycles=${BUNNY_CYCLES:-16}
    if [ "$cycles" != 0 ]; then
        if [ -z "$BUNNY" ]; then
            BUNNY=outputs/data/bunny_c${cycles}_d20_s0_r256
            generate "$BUNNY" object=bunny "cycles=$cycles" drops=20
        fi
        $PY scripts/dev/carry_dataset.py pack "$BUNNY" .carry/bunny.tar.xz
        $PY scripts/dev/carry_dataset.py verify "$BUNNY" .carry/bunny.tar.xz
        # the bunny's mesh is in ../shared, which does not travel: the table1 step names this copy
        mesh=$($PY -c "import json, sys; print(json.load(open(sys.argv[1]))['mesh'])" "$BUNNY/object.json")
        mkdir -p .carry/meshes
        cp "$mesh" .carry/meshes/
    else  # none carried: the run finds no table1 data
        rm -rf .carry/bunny.tar.xz .carry/meshes
    fi
    set +e
    # what a call carries: the tracked and the untracked-not-ignored files, and the carried folders
    $PY - "$WHEELS" .carry <<'EOF'
import os
import subprocess
import sys
from pathlib import Path

listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                        capture_output=True, check=True).stdout.split(b"\0")
tree = sum(os.path.getsize(f) for f in listed if f and os.path.isfile(f))
carried = {d: sum(p.stat().st_size for p in Path(d).rglob("*") if p.is_file()) for d in sys.argv[1:]}
for d in sys.argv[1:]:
    for p in sorted(Path(d).rglob("*")):
        if p.is_file():
            print(f"  {p.stat().st_size / 2**20:6.2f} MiB  {p}")
total = tree + sum(carried.values())
parts = ", ".join(f"{d} {n / 2**20:.1f} MiB" for d, n in carried.items())
print(f"travels: the working tree {tree / 2**20:.1f} MiB, {parts}: {total / 2**20:.1f} MiB of the 64 MiB of a call")
EOF
    echo "carry: $WHEELS .carry; run: DATA=.carry/data.tar.xz scripts/dev/gpu_check.sh (table1: .carry/bunny.tar.xz, found)"
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
if [ -z "$BUNNY" ] && [ -f .carry/bunny.tar.xz ]; then BUNNY=.carry/bunny.tar.xz; fi
mkdir -p "$DEST"
DEST=$(cd "$DEST" && pwd)
(cd "$DEST" && rm -f gpu_check.log summary.md latency.csv infer.csv train_throughput.csv quickstart.csv table1.csv \
    tests.log)  # this script's files of an earlier run (tests.log: of its older versions)
WORK=$(mktemp -d "${TMPDIR:-/tmp}/opnet_gpu_check.XXXXXX")
LOG=$DEST/gpu_check.log
SUMMARY=$DEST/summary.md
START=$(date +%s)
FAILED=0
: >"$LOG"
say() { echo "$*" | tee -a "$LOG"; }
# max_time SECONDS: trainer.max_time's DD:HH:MM:SS (exported: the steps run their functions in a bash of their own)
max_time() { printf '00:%02d:%02d:%02d' $(($1 / 3600)) $(($1 / 60 % 60)) $(($1 % 60)); }
export -f max_time
elapsed() { echo $(($(date +%s) - START)); }

if [ "$MODE" = gpu ]; then
    say "gpu_check: CUDA found ($($PY -c 'import torch; print(torch.cuda.get_device_name())')): the full check, budget ${BUDGET_S} s"
    MODEL=paper BATCHES=1,32 REPEATS=10 STEPS=40 WARMUP=10 WORKERS=8
    TRAIN_EXTRA=(experiment=paper data.generate=null)
    QUICK=(experiment=quickstart trainer=gpu data.num_workers=8)
    # four arms at once on 16 cores: 3 loader workers each; an epoch of the 12 training piles is 8 steps: validated
    # every 5th
    TABLE1=(experiment=paper trainer=gpu data.num_workers=3 trainer.check_val_every_n_epoch=5)
    TABLE1_STEPS=${TABLE1_STEPS:-400} TABLE1_S=${TABLE1_S:-180} TABLE1_MIN_S=100
    ACCEL=gpu ARM=bf16+cl
else
    say "gpu_check: no CUDA device: a CPU dry run of the same steps with tiny sizes, budget ${BUDGET_S} s"
    MODEL=tiny BATCHES=1,2 REPEATS=2 STEPS=2 WARMUP=1 WORKERS=0
    TRAIN_EXTRA=(experiment=paper data.generate=null model=tiny data.batch_size=4 trainer=cpu)
    # one epoch of the first 3 training piles (the carried dataset has 120)
    QUICK=(experiment=quickstart model=tiny trainer.max_epochs=1 data.batch_size=4 data.num_workers=0
           data.cache_workers=1 example_predictions=0 data.train_groups=3)
    TABLE1=(experiment=paper model=tiny trainer=cpu data.batch_size=4 data.num_workers=0 data.cache_workers=1
            data.train_groups=2)
    TABLE1_STEPS=${TABLE1_STEPS:-2} TABLE1_S=${TABLE1_S:-300} TABLE1_MIN_S=30
    ACCEL=cpu ARM=fp32
fi
printf '# gpu_check (%s)\n\n| step | status | seconds |\n|---|---|---|\n' "$MODE" >"$SUMMARY"

# step NAME SECONDS COMMAND...: run with a time limit (cut to what is left of the budget), log, record in the summary
step() {
    local name=$1 limit=$2
    shift 2
    if [ -n "${ONLY:-}" ] && [[ " $ONLY " != *" ${name%%_*} "* ]] && [[ " $ONLY " != *" $name "* ]]; then
        return 0  # not asked for (ONLY)
    fi
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
# shellcheck disable=SC2329  # run through step
install() {
    local py=$1
    local before after missing
    before=$($py -c "import torch; print(torch.__version__, torch.__file__)") || return 1
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
        $py -m pip install -q --no-index --no-deps --no-compile $missing || return 1
    else
        echo "no carried wheel needed (every one's distribution is installed or on PYTHONPATH)"
    fi
    # opnet itself: from this tree's src/ (PYTHONPATH, or an editable install made before), else installed editable
    # (conf/ and the scripts stay where they are)
    local src
    src="$(pwd)/src/"
    if (cd / && $py -c "import opnet, sys; sys.exit(0 if opnet.__file__.startswith(sys.argv[1]) else 1)" "$src") \
        2>/dev/null; then
        echo "opnet imports from $src already: not installed"
    else
        $py -m pip install -q --no-index --no-deps --no-build-isolation -e . || return 1
    fi
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
    if [ -n "$DATA" ]; then  # nothing to generate: hide what the GPU machine lacks too (a None in sys.modules)
        cat >"$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/sitecustomize.py" <<'EOF'
# gpu_check.sh's dry run: the generator's packages are absent on the GPU machine, so they are here
import sys

for _name in ("mujoco", "coacd", "pyrender", "OpenGL", "pybullet", "pyglet", "glfw", "freetype"):
    sys.modules.setdefault(_name, None)
EOF
        say "dry run: mujoco, coacd, pyrender, OpenGL, pybullet, pyglet, glfw, freetype hidden in $WORK/venv"
    fi
    step install 120 install "$PY"
fi
if ! (cd / && $PY -c "import opnet") 2>/dev/null; then  # the editable install failed: this tree's src/ then
    export PYTHONPATH="$ROOT/src${PYTHONPATH:+:$PYTHONPATH}"
    say "opnet is not installed: from PYTHONPATH=$PYTHONPATH"
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
    step pack 60 "$PY" scripts/dev/carry_dataset.py pack "$WORK/generated" "$WORK/data.tar.xz"
    DATA=$WORK/data.tar.xz
fi
if [ -n "$DATA" ] && [ -f "$DATA" ]; then
    step unpack 120 "$PY" scripts/dev/carry_dataset.py unpack "$DATA" "$WORK/data"
    DATA=$WORK/data
fi
if [ -z "$DATA" ] || [ ! -d "$DATA" ]; then
    say "no dataset (DATA=${DATA:-unset}): the training and quickstart steps are skipped"
fi

export OPNET_PILE=${DATA:-}  # the device tests read rendered frames from it instead of rendering their own
# the whole pytest output goes into gpu_check.log
step tests 150 "$PY" -m pytest -q -p no:cacheprovider tests/unit/test_device_side.py tests/unit/test_inference.py \
    tests/unit/test_bench_infer.py -k "not shared"

# ---- 3. latency --------------------------------------------------------------------------------------------------
DEVICE=cpu
[ "$MODE" = gpu ] && DEVICE=cuda
step latency 120 "$PY" scripts/bench/bench_infer.py --device "$DEVICE" --model "$MODEL" --batches "$BATCHES" \
    --repeats "$REPEATS" --parameterizations "" --no-onnx --out "$DEST/infer.csv" --latency-out "$DEST/latency.csv"

# ---- 4. training throughput and 5. the quickstart ---------------------------------------------------------------
if [ -n "$DATA" ] && [ -d "$DATA" ]; then
    step train_throughput 120 "$PY" scripts/bench/bench_train.py --data "$DATA" --accelerator "$ACCEL" --arms "$ARM" \
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

# ---- 6. table1: the paper's arms for the bunny, four at once -------------------------------------------------------
# table1 PY DATA MESH SECONDS STEPS RUNS CSV MODE OVERRIDES...: each arm stops at STEPS optimizer steps or when
# trainer.max_time (SECONDS less the start-up and the test) is up, whichever comes first
# shellcheck disable=SC2329  # run through step
table1() {
    local py=$1 data=$2 mesh=$3 limit=$4 steps=$5 runs=$6 csv=$7 mode=$8
    shift 8
    local train_s=$((limit - 60)) fit arm pids=() rc=0
    [ "$train_s" -lt 20 ] && train_s=20
    fit=$(max_time "$train_s")
    mkdir -p "$runs"
    echo "table1: 4 arms at once, each ${steps} steps or ${train_s} s of fitting"
    for arm in vanilla eve ap si; do
        (
            t0=$(date +%s)
            "$py" train.py "$@" object=bunny "object.mesh=$mesh" "parameterization=$arm" seed=0 data=ipa \
                "data.root=$data" data.generate=null "data.cache_dir=$runs/cache_$arm" example_predictions=0 \
                "trainer.max_steps=$steps" "+trainer.max_time=\"$fit\"" \
                trainer.enable_progress_bar=false hydra.run.dir="$runs/$arm" >"$runs/$arm.log" 2>&1
            echo "$? $(($(date +%s) - t0))" >"$runs/$arm.status"
        ) &
        pids+=($!)
    done
    for pid in "${pids[@]}"; do wait "$pid"; done
    for arm in vanilla eve ap si; do
        echo "---- table1 arm $arm: the end of its console"
        tail -n 25 "$runs/$arm.log"
    done
    "$py" - "$runs" "$csv" "$mode" "$steps" <<'EOF' || rc=1
import csv
import json
import sys
from pathlib import Path

runs, out, mode, steps = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
rows, failed = [], 0
for arm in ("vanilla", "eve", "ap", "si"):
    status = (runs / f"{arm}.status").read_text().split() if (runs / f"{arm}.status").is_file() else ["?", ""]
    summary = runs / arm / "test" / "summary.json"
    result = json.loads(summary.read_text()) if summary.is_file() else {}
    curve_file = runs / arm / "learning_curve.csv"  # a row per validation (none when max_steps comes first)
    curve = list(csv.DictReader(curve_file.open())) if curve_file.is_file() else []
    last = curve[-1] if curve else {}
    done = last.get("step", "")  # the optimizer steps: last.ckpt's (written at the end of every epoch, the last too)
    try:
        from opnet.cli.build import read_checkpoint

        done = read_checkpoint(runs / arm / "checkpoints" / "last.ckpt").get("global_step", done)
    except (OSError, ValueError) as e:
        print(f"table1 {arm}: {e}")
    diag = result.get("diagnostics") or {}
    found = round(diag["matched"] / diag["to_find"], 4) if diag.get("to_find") else ""
    ok = status[0] == "0" and "ap" in result
    failed += not ok
    rows.append({
        "mode": mode, "parameterization": arm, "status": "ok" if ok else f"failed (exit {status[0]})",
        "steps": done, "max_steps": steps, "seconds": status[1],
        # fitting without validation, at the last validation
        "train_seconds": round(float(last["train_minutes"]) * 60, 1) if last else "",
        "val_ap": last.get("val_ap", ""), "test_ap": result.get("ap", ""), "found": found,
        "test_scenes": result.get("scenes", ""),
    })
with out.open("w", newline="") as f:
    writer = csv.DictWriter(f, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
for row in rows:
    print(f"table1 {row['parameterization']:8s}: {row['status']}, {row['steps']} steps, {row['seconds']} s, "
          f"test AP {row['test_ap']}")
sys.exit(1 if failed else 0)
EOF
    return "$rc"
}

if [ -n "$BUNNY" ]; then
    MESH=$ROOT/.carry/meshes/SileaneBunny.obj
    [ -f "$MESH" ] || MESH=$(cd "$ROOT/.." && pwd)/shared/data/meshes/SileaneBunny.obj
    if [ -f "$BUNNY" ]; then
        step unpack_bunny 120 "$PY" scripts/dev/carry_dataset.py unpack "$BUNNY" "$WORK/bunny"
        BUNNY=$WORK/bunny
    fi
    left=$((BUDGET_S - $(elapsed)))
    if [ ! -d "$BUNNY" ] || [ ! -f "$MESH" ]; then
        say "table1: no bunny dataset or mesh (BUNNY=$BUNNY, mesh $MESH): skipped"
    elif [ "$left" -lt "$TABLE1_MIN_S" ]; then  # the arms would stop before they learn anything
        say "== table1: skipped, ${left} s of the budget left (it needs ${TABLE1_MIN_S} s)"
        echo "| table1 | skipped (budget: ${left} s left) | 0 |" >>"$SUMMARY"
    else
        [ "$TABLE1_S" -gt "$left" ] && TABLE1_S=$left
        step table1 "$TABLE1_S" table1 "$PY" "$(cd "$BUNNY" && pwd)" "$MESH" "$TABLE1_S" "$TABLE1_STEPS" \
            "$WORK/table1" "$DEST/table1.csv" "$MODE" "${TABLE1[@]}"
    fi
fi

# ---- 7. arms: Table I of another object, experiment=table1 (scripts/experiments/table1/table1.py), JOBS arms at once ------------------
# ARMS_DATA: the object's experiment=table1 dataset (a folder or a carry_dataset.py archive), ARMS_OBJECT its name;
# its mesh under $OPNET_SHARED as the object's config names it. The arms' small files (configs, test summaries, tuned
# decodings, learning curves, consoles) come back as arms_<object>.tar.gz.
if [ -n "${ARMS_DATA:-}" ]; then
    ARMS_OBJECT=${ARMS_OBJECT:?ARMS_OBJECT: the object of ARMS_DATA}
    if [ -f "$ARMS_DATA" ]; then
        step unpack_arms 120 "$PY" scripts/dev/carry_dataset.py unpack "$ARMS_DATA" "$WORK/arms_data"
        ARMS_DATA=$WORK/arms_data
    fi
    ARMS_RUNS=$WORK/arms
    ARMS_S=${ARMS_S:-600}
    # a guard, not the budget: fitting stops after ARMS_S less 150 s (start-up, test and tuning after it), so that a
    # slow call still brings its arms back scored; learning_curve.csv then shows steps short of ARMS_STEPS
    fit_s=$((ARMS_S - 150))
    [ "$fit_s" -lt 30 ] && fit_s=30
    if [ "$MODE" = gpu ]; then
        ARMS_EXTRA=(trainer=gpu "+trainer.max_time=\"$(max_time "$fit_s")\"")
        ARMS_STEPS=${ARMS_STEPS:-1350} ARMS_SEEDS=${ARMS_SEEDS:-0 1 2} ARMS_JOBS=${ARMS_JOBS:-18}
    else  # two arms of a few steps
        ARMS_EXTRA=(trainer=cpu model=tiny data.train_groups=2 data.cache_workers=1)
        ARMS_STEPS=${ARMS_STEPS:-2} ARMS_SEEDS=${ARMS_SEEDS:-0} ARMS_JOBS=${ARMS_JOBS:-2}
        ARMS_PARAMS=${ARMS_PARAMS:-vanilla,si}
    fi
    # shellcheck disable=SC2086  # the seeds are words
    step arms "$ARMS_S" "$PY" scripts/experiments/table1/table1.py --objects "$ARMS_OBJECT" \
        --parameterizations "${ARMS_PARAMS:-vanilla,eve,ap,z,mp,si}" --seeds $ARMS_SEEDS --steps "$ARMS_STEPS" \
        --jobs "$ARMS_JOBS" --runs-dir "$ARMS_RUNS" --out "$WORK/arms_table" \
        --extra "data.root=$ARMS_DATA" data.generate=null example_predictions=0 "${ARMS_EXTRA[@]}"
    [ -f "$WORK/arms_table/README.md" ] && cat "$WORK/arms_table/README.md" >>"$LOG"
    if [ -d "$ARMS_RUNS" ]; then
        (cd "$ARMS_RUNS" && find . \( -path '*/.hydra/*' -o -path '*/test/summary.json' -o -path '*/test/ap_table.md' \
            -o -name decoding_tuned.json -o -name learning_curve.csv -o -name '*.log' \) -type f -print \
            | tar czf "$DEST/arms_$ARMS_OBJECT.tar.gz" -T -)
        say "arms: $(find "$ARMS_RUNS" -path '*/test/summary.json' | wc -l) arm(s) scored -> arms_$ARMS_OBJECT.tar.gz"
    fi
fi

# ---- 8. budget: the cell's one command at several times its steps (cells.py --stage budget), all at once ---------
# CELL_DATA: its training piles with their scene cache (a carry_dataset.py pack-cache archive named as the dataset,
# <dataset>.tar.xz, unpacked into a folder of that name, or the folder);
# CELL_SHARED: the reference-data folder (OPNET_SHARED) holding data/ipd_real_obj18: the camera file and the mesh.
# Each budget's best checkpoint comes back as budget_x<m>_<its name>, the runs' small files as budget.tar.gz; then,
# here: `cells.py --stage budget-report --collect <the folder of those files>` scores them on the test piles.
if [ -n "${CELL_DATA:-}" ]; then
    if [ -f "$CELL_DATA" ]; then
        name=$(basename "$CELL_DATA" .tar.xz)
        step unpack_cell 120 "$PY" scripts/dev/carry_dataset.py unpack "$CELL_DATA" "$WORK/cell_data/$name"
        CELL_DATA=$WORK/cell_data/$name
    fi
    CELL_S=${CELL_S:-480}
    if [ "$MODE" = gpu ]; then  # fitting stops 60 s before the step's limit, so that every budget saves its best
        read -r -a multiples <<<"${CELL_MULTIPLES:-1 2 4}"
        CELL_EXTRA=(trainer=gpu "+trainer.max_time=\"$(max_time $((CELL_S - 60)))\""
                    "data.num_workers=$(((${CELL_CORES:-16} - ${#multiples[@]}) / ${#multiples[@]}))")
    else  # six steps of each budget on the first two piles (epochs of three steps: each validates, then saves)
        CELL_EXTRA=(trainer.max_steps=6 +trainer.limit_val_batches=2 data.train_groups=2 data.num_workers=0
                    data.cache_workers=1)
        CELL_VAL_EVERY=${CELL_VAL_EVERY:-1}
        read -r -a multiples <<<"${CELL_MULTIPLES:-1 2}"
    fi
    step budget "$CELL_S" env OPNET_SHARED="$(cd "${CELL_SHARED:?CELL_SHARED: the folder of the camera file and mesh of the cell}" && pwd)" \
        "$PY" scripts/experiments/cells/cells.py --stage budget --multiples "${multiples[@]}" --jobs "${#multiples[@]}" \
        --val-every "${CELL_VAL_EVERY:-2}" --runs "$WORK/cells" --extra "data.root=$CELL_DATA" data.generate=null \
        data.check=off "${CELL_EXTRA[@]}"
    for run in "$WORK"/cells/budget/x*; do
        [ -d "$run" ] || continue
        best=$("$PY" -c "import sys; from opnet.paths import best_checkpoint; print(best_checkpoint(sys.argv[1]) or '')" "$run")
        [ -n "$best" ] && cp "$best" "$DEST/budget_$(basename "$run")_$(basename "$best")"
        say "budget $(basename "$run"): $(tail -n 1 "$run/learning_curve.csv" 2>/dev/null) best ${best##*/}"
    done
    [ -d "$WORK/cells/budget" ] && (cd "$WORK/cells" && find budget \( -path '*/.hydra/*' -o -name learning_curve.csv \
        -o -name '*.log' \) -type f -print | tar czf "$DEST/budget.tar.gz" -T -)
fi

say "== done in $(elapsed) s of ${BUDGET_S}, ${FAILED} failed step(s); results in $DEST"
find "$DEST" -maxdepth 1 -type f -printf "%f\n" | sort | tee -a "$LOG"
cat "$SUMMARY"
rm -rf "$WORK"
exit "$FAILED"
