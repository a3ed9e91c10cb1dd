"""Fuzz the public entry points with generated bad input (hypothesis).

Every generated input must end in a *named* error (``ConfigError``/``ValueError`` naming the field,
a Gymnasium error, or argparse's exit with a message naming the option) or in a documented
outcome (the value happens to be allowed, so it is accepted) -- never in an exception from deep
inside. ``pytest -s tests/test_fuzz.py`` prints the tally of inputs tried and how each ended.
"""

from __future__ import annotations

import copy
import math
from collections import Counter

import numpy as np
import pytest

from hypothesis import HealthCheck, given, settings  # the dev extra; CI installs it
from hypothesis import strategies as st

from bogie_env.envs.config import default_config, make_config
from bogie_env.params import FIELDS, ConfigError, load_params

def fast(max_examples: int):
    """Bounded and deterministic: fixed examples per run, no per-example deadline (numba compiles cold)."""
    return settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
TALLY: Counter = Counter()


@pytest.fixture(scope="module", autouse=True)
def report_tally():
    yield
    total = sum(v for k, v in TALLY.items() if k[1] != "checked")
    print(f"\nfuzz tally ({total} inputs):")
    for (entry, outcome), count in sorted(TALLY.items()):
        print(f"  {entry:14s} {outcome:22s} {count}")


def _leaves(config: dict, prefix: tuple = ()) -> list[tuple]:
    out = []
    for key, value in config.items():
        path = prefix + (key,)
        if isinstance(value, dict) and value and key not in ("bogie_overrides", "randomize"):
            out += _leaves(value, path)
        else:
            out.append(path)
    return out


LEAVES = _leaves(default_config())
BAD_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**12), 10**12),
    st.text(max_size=6),
    st.none(),
    st.booleans(),
    st.lists(st.floats(-1e3, 1e3), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)
PARAM_NAMES = st.one_of(st.sampled_from(sorted(FIELDS)), st.text(min_size=1, max_size=6))


def _assert_names(error: Exception, *names: str) -> None:
    message = str(error)
    assert any(str(name) in message or repr(str(name))[1:-1] in message for name in names), f"{message!r} names none of {names}"


@fast(150)
@given(path=st.sampled_from(LEAVES), value=BAD_VALUES, unknown=st.booleans(), extra=st.text(min_size=1, max_size=6))
def test_env_config_values(path, value, unknown, extra):
    config: dict = {}
    node = config
    for key in path[:-1]:
        node = node.setdefault(key, {})
    leaf = path[-1]
    if unknown and extra not in (default_config().get(path[0], {}) if len(path) > 1 else default_config()):
        node[extra] = value  # an unknown key at this level
        named = (extra,)
    else:
        node[leaf] = value
        named = (leaf,) + tuple(map(str, value)) if isinstance(value, dict) else (leaf,)
    try:
        made = make_config(config)
    except ConfigError as error:
        _assert_names(error, *named, "weights")  # the reward weights' sum is named as such
        TALLY["make_config", "ConfigError (named)"] += 1
        return
    TALLY["make_config", "accepted (allowed)"] += 1
    if path[0] == "randomize" and made["randomize"]:  # accepted ranges must not fail at a later reset
        from bogie_env.envs.task import HuntingTask

        task = HuntingTask(1, made)
        for seed in range(3):
            task.seed_rows(np.array([0]), [seed])
            task.reset_rows(np.array([0]))


@fast(60)
@given(overrides=st.dictionaries(PARAM_NAMES, st.one_of(BAD_VALUES, st.floats(-1e12, 1e12)), min_size=1, max_size=2))
def test_env_config_bogie_overrides_and_randomize(overrides):
    for key in ("bogie_overrides", "randomize"):
        try:
            make_config({key: overrides})
        except ConfigError as error:
            _assert_names(error, *map(str, overrides), key)
            TALLY["make_config", "ConfigError (named)"] += 1
        else:
            TALLY["make_config", "accepted (allowed)"] += 1


SET_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**15), 10**15).map(str),
    st.text(max_size=8),
    st.sampled_from(["nan", "inf", "-inf", "1e400", "", "0x10", "1,5", "None", "true"]),
)


@fast(80)
@given(name=PARAM_NAMES, value=SET_VALUES, separator=st.sampled_from(["=", "=", ":", ""]))
def test_set_values(name, value, separator):
    item = f"{name}{separator}{value}"
    try:
        load_params(None, [item])
    except ConfigError as error:
        _assert_names(error, name.strip(), item)
        TALLY["--set", "ConfigError (named)"] += 1
    else:
        TALLY["--set", "accepted (allowed)"] += 1


_ENV = {}


def _env():
    if "env" not in _ENV:
        import gymnasium as gym

        import bogie_env  # noqa: F401

        _ENV["env"] = gym.make("Bogie/Hunting-v0")
        _ENV["env"].reset(seed=0)
    return _ENV["env"]


ACTIONS = st.one_of(
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=0, max_size=6).map(np.array),
    st.lists(st.floats(-1e30, 1e30), min_size=4, max_size=4).map(lambda v: np.array(v, dtype=np.float32)),
    st.just(np.zeros((2, 4))),
    st.just("left"),
    st.none(),
    st.lists(st.text(max_size=2), min_size=4, max_size=4).map(np.array),
)


@fast(80)
@given(action=ACTIONS)
def test_env_step_actions(action):
    import gymnasium as gym

    env = _env()
    try:
        _, reward, terminated, truncated, _ = env.step(action)
    except (ValueError, TypeError, gym.error.Error) as error:
        assert "action" in str(error).lower() or "shape" in str(error).lower(), str(error)
        TALLY["env.step", f"{type(error).__name__} (named)"] += 1
        return
    assert math.isfinite(reward)
    TALLY["env.step", "accepted (clipped)"] += 1
    if terminated or truncated:
        env.reset(seed=1)


@fast(40)
@given(options=st.dictionaries(st.sampled_from(["start_kmh", "end_kmh", "accel", "params", "speed"]),
                               st.one_of(BAD_VALUES, st.floats(-1e4, 1e4)), min_size=1, max_size=3))  # fmt: skip
def test_env_reset_options(options):
    env = _env()
    try:
        env.reset(seed=0, options=copy.deepcopy(options))
    except ConfigError as error:
        params = options.get("params")
        _assert_names(error, *options, *(params if isinstance(params, dict) else ()), "start_kmh", "reset option")
        TALLY["env.reset", "ConfigError (named)"] += 1
    else:
        TALLY["env.reset", "accepted (allowed)"] += 1


def _out_of_range_number():
    return st.one_of(st.floats(-1e6, -0.05).map(repr), st.floats(1e4, 1e12).map(repr),
                     st.sampled_from(["nan", "inf", "-inf", "x", "", "1..2", "--"]))  # fmt: skip


CLI_ARGS = st.one_of(
    st.tuples(st.sampled_from(["critical-speed", "root-locus", "bifurcation", "ramp"]),
              st.sampled_from(["--v-min-kmh", "--v-max-kmh"]), _out_of_range_number()).map(list),
    st.tuples(st.just("ramp"), st.sampled_from(["--accel", "--offset", "--track-rms", "--track-seed"]),
              st.one_of(_out_of_range_number(), st.just("-1"))).map(list),
    st.tuples(st.just("critical-speed"), st.just("--set"),
              st.tuples(st.text(alphabet="XYZqkw_", min_size=1, max_size=5), SET_VALUES).map("=".join)).map(list),
    st.tuples(st.just("critical-speed"), st.just("--set"),
              st.tuples(st.sampled_from(["Csy", "Kpx", "lam", "mb", "delta"]),
                        st.sampled_from(["-1", "nan", "inf", "abc", "1e30", "-0.5", ""])).map("=".join)).map(list),
    st.tuples(st.just("bifurcation"), st.just("--rates"), st.sampled_from(["", ",", "a", "1,-1", "0", "nan", "1,,x"])).map(list),
    st.tuples(st.just("sensitivity"), st.just("--param"), st.text(alphabet="abcQ_", min_size=1, max_size=4)).map(list),
    st.tuples(st.just("evaluate"), st.just("--policy"), st.text(alphabet="abc/._", min_size=1, max_size=8)).map(list),
    st.tuples(st.just("evaluate"), st.just("--parts"), st.text(alphabet="xyz1,", min_size=0, max_size=6)).map(
        lambda t: ["evaluate", "--policy", "passive", *t]),
    st.tuples(st.sampled_from(["critical-speed", "evaluate", "train", "ramp"]),
              st.sampled_from(["--config", "--env-config"]), st.text(alphabet="abc/.", min_size=1, max_size=8)).map(
        lambda t: [t[0], *(["--policy", "passive"] if t[0] == "evaluate" else ["--out", "/nonexistent/x"] if t[0] == "train" else []),
                   "--config" if t[0] in ("train", "critical-speed", "ramp") else t[1], t[2]]),
    st.tuples(st.sampled_from(["--frobnicate", "-x", "--seed"]), st.text(max_size=4)).map(lambda t: ["ramp", *t]),
)


@fast(120)
@given(argv=CLI_ARGS)
def test_cli_main(argv):
    import contextlib
    import io

    from bogie_agents.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(list(argv))
        except SystemExit as exit_:
            code = exit_.code
            outcome = "argparse exit (named)"
        else:
            outcome = "error exit (named)"
    text = err.getvalue()
    if code == 0:
        TALLY["cli main", "accepted (allowed)"] += 1
        return
    assert code == 2, (argv, code, text)
    assert "error:" in text and "Traceback" not in text, (argv, text)
    TALLY["cli main", outcome] += 1
