"""The -v4 ids keep their trajectories bitwise.

``tests/data/v4_golden.npz`` was written by this file's ``__main__`` when v4 was added, with the
same seeded runs as v1's, v2's and v3's golden files (``tests/test_v1_golden.py``). Adding v4
touched no kernel (a new entry of ``integrate.METHOD_DIVISORS``), and the v0-v3 golden tests
pass unchanged. A change that moves a v4 trajectory by one bit fails here; such a change belongs
in a new env id.

    PYTHONPATH=<tree> python tests/test_v4_golden.py   # writes the golden file (only for a new version)
"""

from pathlib import Path

import numpy as np
import pytest

import bogie_env  # noqa: F401  (registers the ids)
from tests.golden_runs import assert_bitwise, runs as golden_runs
from tests.test_v1_golden import N_STEPS, single_run  # the same seeded runs as v1's

GOLDEN = Path(__file__).parent / "data" / "v4_golden.npz"
IDS = ("Bogie/Hunting-v4", "Bogie/HuntingPassive-v4")


@pytest.mark.parametrize("env_id", IDS)
def test_v4_trajectories_are_bitwise_unchanged(env_id):
    assert_bitwise(GOLDEN, env_id, single_run, N_STEPS)


if __name__ == "__main__":
    np.savez_compressed(GOLDEN, **golden_runs(IDS, single_run, N_STEPS))
    print(f"wrote {GOLDEN}")
