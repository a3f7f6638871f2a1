"""Moved to scripts/bench/bench_train.py; this path runs it until scripts/gpu_check.sh names the new one."""

import runpy

from opnet.paths import REPO_ROOT

runpy.run_path(str(REPO_ROOT / "scripts" / "bench" / "bench_train.py"), run_name="__main__")
