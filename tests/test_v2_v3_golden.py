"""The -v2 and -v3 ids keep their trajectories bitwise.

``tests/data/v2_v3_golden.npz`` was written by this file's ``__main__`` when v3 was added
(observations, rewards, end states and actuator forces of seeded runs with seeded random
actions, in the single env and the native vector env, as ``tests/test_v1_golden.py``). The
kernels had just been changed to take stage divisors instead of a stage count; v2's trajectories
(random actions, resets, 300 steps of v1, v2, v0 and v1_semi_active) were compared with the code
before that change and were equal bit for bit. A change that moves a v2 or v3 trajectory by one
bit fails here; such a change belongs in a new env id.

    PYTHONPATH=<tree> python tests/test_v2_v3_golden.py   # writes the golden file (only for a new version)
"""

from pathlib import Path

import numpy as np
import pytest

import bogie_env  # noqa: F401  (registers the ids)
from tests.golden_runs import assert_bitwise, runs as golden_runs
from tests.test_v1_golden import N_STEPS, single_run  # the same seeded runs as v1's

GOLDEN = Path(__file__).parent / "data" / "v2_v3_golden.npz"
IDS = ("Bogie/Hunting-v2", "Bogie/HuntingPassive-v2", "Bogie/Hunting-v3", "Bogie/HuntingPassive-v3")


def runs() -> dict[str, np.ndarray]:
    return golden_runs(IDS, single_run, N_STEPS)


@pytest.mark.parametrize("env_id", IDS)
def test_v2_v3_trajectories_are_bitwise_unchanged(env_id):
    assert_bitwise(GOLDEN, env_id, single_run, N_STEPS)


if __name__ == "__main__":
    np.savez_compressed(GOLDEN, **runs())
    print(f"wrote {GOLDEN}")
