"""Shared fixtures: the paper's bogie, built once per test session."""

import os

# Before numba or torch loads OpenMP: its worker threads sleep between parallel regions instead
# of spinning. The suite calls parallel kernels (model.rhs) thousands of times on one or a few
# rows; on a busy 2-core host spinning threads made each call cost ~8 ms of CPU instead of ~0.03.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bogie_env.dynamics import BogieModel
from bogie_env.params import BogieParams  # noqa: E402
from bogie_env.stability import linearize  # noqa: E402


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


def pytest_collection_modifyitems(config, items):
    """Tests that start a Ray cluster (10-20 s of start-up on 2 cores) run with the slow ones:
    `make test` stays within its 3 minutes, and CI runs them in `make test-slow`."""
    for item in items:
        if "ray_cluster" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)
