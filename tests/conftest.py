"""Shared fixtures: the paper's bogie, built once per test session."""

import numpy as np
import pytest

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


def pytest_collection_modifyitems(config, items):
    """Tests that start a Ray cluster (10-20 s of start-up on 2 cores) run with the slow ones:
    `make test` stays within its 3 minutes, and CI runs them in `make test-slow`."""
    for item in items:
        if "ray_cluster" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)
