"""Shared fixtures: the paper's bogie, built once per test session."""

import numpy as np
import pytest

# importing bogie_env sets OMP_WAIT_POLICY=PASSIVE unless set, before numba's OpenMP starts: the
# suite calls parallel kernels (model.rhs) thousands of times on one or a few rows
from bogie_env.dynamics import BogieModel
from bogie_env.params import BogieParams
from bogie_env.stability import linearize


@pytest.fixture(scope="session")
def paper_params() -> BogieParams:
    return BogieParams.paper()


@pytest.fixture(scope="session")
def paper_model(paper_params) -> BogieModel:
    return BogieModel(paper_params)


@pytest.fixture(scope="session")
def paper_linearization(paper_model):
    return linearize(paper_model)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


#: What a second process compiles meanwhile: kernels that do not call the integrator (the
#: linearisation and equilibrium, a v1 task's reset with its sensors), so the two never compile
#: the same function.
_OTHER_KERNELS = """
import numpy as np
from bogie_env.dynamics import BogieModel
from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask
from bogie_env.stability import linearize
linearize(BogieModel())
task = HuntingTask(2, make_config(variant="v1"))
task.seed_rows(np.arange(2), [0, 1])
task.reset_rows(np.arange(2))
"""


def pytest_configure(config):
    """On a cold numba cache (a clean clone) the xdist controller compiles the lane-block
    integrator once, before the workers start, and a second process the kernels that do not
    call it; otherwise every worker compiles them at once (about 70 s of CPU each). With a warm
    cache this takes a second or two."""
    if getattr(config.option, "numprocesses", None) and not hasattr(config, "workerinput"):
        import subprocess
        import sys
        import time

        from bogie_env.simulator import BatchSimulator

        started = time.perf_counter()
        other = subprocess.Popen([sys.executable, "-c", _OTHER_KERNELS], cwd=config.rootpath)
        try:
            BatchSimulator(BogieModel(BogieParams.paper()), 9).run(1)  # 9 rows: the lane blocks of 8 and of 1
        finally:
            if other.wait() != 0:  # the workers compile what it did not; say so, the tests still run
                print(f"numba warm-up: the second process exited with {other.returncode}")
        if time.perf_counter() - started > 5.0:
            print(f"numba: the shared kernels compiled once for the workers in {time.perf_counter() - started:.0f} s (cached)")


def pytest_collection_modifyitems(config, items):
    """Tests that start a Ray cluster (10-20 s of start-up on 2 cores) run with the slow ones:
    `make test` stays within its 3 minutes, and CI runs them in `make test-slow`."""
    for item in items:
        if "ray_cluster" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session", autouse=True)
def _each_track_profile_built_once():
    """Every HuntingTask builds its 262 km alignment profile (an FFT of 2^20 points, ~60 ms of
    CPU); the suite builds a few hundred tasks on a few tracks (v0's default, v1's "alert"
    level). Within the session each distinct profile is built once by the library function and
    every task gets its own copy of the values. Only the env's and the ramp analysis' references
    are wrapped: tests of bogie_env.track call its functions themselves."""
    from bogie_env.analysis import ramp
    from bogie_env.envs import task
    from bogie_env.track import TrackProfile

    built: dict = {}

    def once(function):
        def wrapper(*args, **kwargs):
            key = (function.__name__, args, tuple(sorted(kwargs.items())))
            if key not in built:
                built[key] = function(*args, **kwargs)
            profile = built[key]
            return TrackProfile(profile.values.copy(), profile.dx)

        return wrapper

    patch = pytest.MonkeyPatch()
    patch.setattr(task, "alignment_profile", once(task.alignment_profile))
    patch.setattr(task, "alignment_profile_at_level", once(task.alignment_profile_at_level))
    patch.setattr(ramp, "alignment_profile", once(ramp.alignment_profile))
    yield
    patch.undo()
