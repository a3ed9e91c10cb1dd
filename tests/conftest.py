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
