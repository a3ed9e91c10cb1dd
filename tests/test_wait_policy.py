"""The library's OpenMP wait policy: PASSIVE unless the user set one, and numba's OpenMP sees it.

Each check runs in a fresh interpreter: OpenMP reads the variable once, when it loads.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest


def _run(code: str, **env_vars: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OMP_DISPLAY_ENV")}
    env.update(env_vars)
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)


PRINT_POLICY = "import bogie_env, os; print(os.environ['OMP_WAIT_POLICY'])"


def test_import_sets_passive_when_unset():
    assert _run(PRINT_POLICY).stdout.strip() == "PASSIVE"


@pytest.mark.parametrize("value", ["ACTIVE", "passive", ""])
def test_a_users_value_is_kept(value):
    assert _run(PRINT_POLICY, OMP_WAIT_POLICY=value).stdout.rstrip("\n") == value


def test_numbas_openmp_runtime_reads_it():
    """libgomp reports its spin count at start-up (OMP_DISPLAY_ENV=VERBOSE): 0 under PASSIVE,
    300000 (about 3 ms of spinning after each parallel region) when the variable is unset."""
    code = ("import bogie_env, numba, numpy as np\n"
            "from bogie_env.dynamics import BogieModel\n"
            "BogieModel().rhs(np.zeros(20), 100.0)  # a parallel kernel: starts numba's threading layer\n"
            "print('layer', numba.threading_layer())")  # fmt: skip
    done = _run(code, OMP_DISPLAY_ENV="VERBOSE")
    assert done.returncode == 0, done.stderr
    if "layer omp" not in done.stdout or "GOMP_SPINCOUNT" not in done.stderr:
        pytest.skip(f"numba's threading layer is not GNU OpenMP here ({done.stdout.strip()})")
    assert re.findall(r"GOMP_SPINCOUNT = '(\d+)'", done.stderr) == ["0"], done.stderr
