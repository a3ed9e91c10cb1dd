"""The reset's cheap draws (bogie_env.envs.draws) against numpy's own, bit for bit, and the
parameter check's fast path against the rule it shortcuts."""

import math

import numpy as np
import pytest

from bogie_env.envs.draws import centred_normal, uniform, uniform_array
from bogie_env.params import FIELDS, ConfigError, validate_value


def _pair(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    return np.random.default_rng(seed), np.random.default_rng(seed)


def test_uniform_matches_numpy_bits_and_stream():
    ours, numpys = _pair(3)
    bounds = np.random.default_rng(4).uniform(-700.0, 700.0, (3000, 2))
    bounds[::7, 1] = bounds[::7, 0]  # zero width
    for low, high in np.sort(bounds, axis=1):
        low, high = float(low), float(high)
        a, b = uniform(ours, low, high), float(numpys.uniform(low, high))
        assert a == b and math.copysign(1.0, a) == math.copysign(1.0, b), (low, high)
    assert ours.random() == numpys.random()  # the streams stay in step


def test_uniform_array_and_centred_normal_match_numpy():
    ours, numpys = _pair(5)
    scales = np.array([0.0, 1e-6, 2e-3, 0.4, 5.0, 0.0])
    for _ in range(500):
        assert np.array_equal(uniform_array(ours, 0.5, 1.5, 4), numpys.uniform(0.5, 1.5, 4))
        a, b = centred_normal(ours, scales), numpys.normal(0.0, scales)
        assert np.array_equal(a, b) and np.array_equal(np.signbit(a), np.signbit(b))  # 0 * -z is +0.0 in both
    assert ours.random() == numpys.random()


@pytest.mark.parametrize("low, high", [(1.0, 0.0), (0.0, math.inf), (math.nan, 1.0)])
def test_uniform_rejects_what_numpy_rejects(low, high):
    for draw in (lambda r: uniform(r, low, high), lambda r: uniform_array(r, low, high, 3)):
        with pytest.raises((ValueError, OverflowError)):
            draw(np.random.default_rng(0))


def test_centred_normal_rejects_negative_scale():
    with pytest.raises(ValueError):
        centred_normal(np.random.default_rng(0), np.array([1.0, -1e-9]))


def _accepted(name: str, value: float) -> bool:
    """The documented rule: in [low, high] (or (low, high]), or +inf where allowed."""
    spec = FIELDS[name]
    if math.isnan(value) or (math.isinf(value) and not (value > 0 and spec.allow_inf)):
        return False
    if math.isinf(value):
        return True
    above = value >= spec.low if spec.low_inclusive else value > spec.low
    return above and value <= spec.high


@pytest.mark.parametrize("name", list(FIELDS))
def test_validate_value_fast_path_keeps_the_rule(name):
    spec = FIELDS[name]
    edges = [spec.low, spec.high, math.inf, -math.inf, math.nan, 0.0, -0.0, 1.0]
    candidates = [e for e in edges if math.isfinite(e)]
    values = edges + [math.nextafter(e, d) for e in candidates for d in (-math.inf, math.inf)]
    for value in values:
        for given in (value, np.float64(value)):  # a float takes the fast path, np.float64 the general one
            if _accepted(name, value):
                out = validate_value(name, given)
                assert type(out) is float and (out == value or (math.isinf(out) and math.isinf(value)))
            else:
                with pytest.raises(ConfigError, match=name):
                    validate_value(name, given)
