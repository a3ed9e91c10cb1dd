"""The route variant of v1 (``Bogie/HuntingRoute-v1``): track input, symmetry, the straight
limit and the curving reward against independent evaluations.

Planted bugs each test catches (checked by hand, docs/environment.md): the curvature sign
flipped in ``bogie_env.wheel_rail.wheelset_details`` (wear oracle); the cant left out of the info's
cant deficiency (geometry test).
"""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import bogie_env  # noqa: F401  (registers the ids)
from bogie_env.dynamics import P_DELTA, P_E, P_F11, P_F12, P_F22, P_F33, P_L1, P_LAM, P_MU, P_R0, P_WPA, state_index
from bogie_env.params import ConfigError
from bogie_env.route import CANT_BASE_M, load_route
from bogie_env.track import (
    ALIGNMENT_WHEELSET1, CANT_FRAME, CANT_WHEELSET1, CANT_WHEELSET2, CURVATURE_FRAME, CURVATURE_WHEELSET1,
    CURVATURE_WHEELSET2,
)  # fmt: skip

#: A short curve so a test runs through it in a few hundred steps.
SHORT = {"name": "short", "design_speed_kmh": 160, "segments": [
    {"type": "tangent", "length": 30}, {"type": "transition", "length": 60},
    {"type": "curve", "length": 200, "radius": 1200, "cant": 0.12, "direction": "left"},
    {"type": "transition", "length": 60}, {"type": "tangent", "length": 30}]}  # fmt: skip
QUIET = {"randomize": {}, "initial_perturbation": 0.0, "track": {"level": None, "rms": 0.0}}


def _route_file(tmp_path: Path, direction: str = "left", curvature: bool = True) -> str:
    data = yaml.safe_load(yaml.safe_dump(SHORT))
    if not curvature:
        data["segments"] = [{"type": "tangent", "length": 380}]
    for seg in data["segments"]:
        if seg["type"] == "curve":
            seg["direction"] = direction
    path = tmp_path / f"short-{direction}-{int(curvature)}.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _run(env, steps: int | None = None, action=None, stop: bool = True):
    """Step until the episode ends (``stop``) or for ``steps``; per-step infos and rewards."""
    infos, rewards = [], []
    while steps is None or len(infos) < steps:
        a = np.zeros(env.action_space.shape) if action is None else action
        _, reward, terminated, truncated, info = env.step(a)
        infos.append(info)
        rewards.append(reward)
        if stop and (terminated or truncated):
            break
    return infos, np.array(rewards)


def test_route_episode_runs_its_route_and_the_track_input_matches_the_geometry():
    env = gym.make("Bogie/HuntingRoutePassive-v1")
    env.reset(seed=0, options={"route": "conventional-1500", "start_kmh": 180.0})
    task = env.unwrapped.task
    route = load_route("conventional-1500")
    slot = task.route_layout.slots[task.route_slot[0]]
    assert task.route_name(0) == "conventional-1500" and task.speed_kmh[0] == 180.0
    L1 = task.P[0, P_L1]
    for _ in range(12):  # 12 x 50 steps of 0.5 s: 300 m, from the tangent into the transition
        _run(env, steps=50, stop=False)
        s = task.distance_m[0] - slot.start_m  # distance along the route file's own geometry
        sample = task.sim.track_sample[0]
        for column, offset in ((CURVATURE_WHEELSET1, L1), (CURVATURE_WHEELSET2, -L1), (CURVATURE_FRAME, 0.0)):
            assert sample[column] == pytest.approx(route.curvature(s + offset), rel=1e-9, abs=1e-15)
        for column, offset in ((CANT_WHEELSET1, L1), (CANT_WHEELSET2, -L1), (CANT_FRAME, 0.0)):
            assert np.sin(sample[column]) * CANT_BASE_M == pytest.approx(route.cant(s + offset), rel=1e-9, abs=1e-15)
        kappa, cant = float(route.curvature(s)), float(route.cant(s))
        if kappa != 0.0:  # the info's cant deficiency: equilibrium cant (EN 13803's base) minus the cant
            equilibrium = CANT_BASE_M * np.sin(np.arctan(50.0**2 * kappa / 9.81))
            assert task.cant_deficiency_m[0] == pytest.approx(np.sign(kappa) * (equilibrium - cant), rel=1e-9)
    assert task.curvature_1pm[0] == sample[CURVATURE_FRAME] < 0  # the info reads the frame's sample (a right-hand curve)


def test_route_options_and_config_errors_name_the_field():
    env = gym.make("Bogie/HuntingRoutePassive-v1")
    with pytest.raises(ConfigError, match="'route'"):
        env.reset(seed=0, options={"route": "nowhere"})
    with pytest.raises(ConfigError, match="end_kmh"):
        env.reset(seed=0, options={"end_kmh": 300.0})
    with pytest.raises(ConfigError, match="route_copy"):
        env.reset(seed=0, options={"route_copy": 99})
    with pytest.raises(ConfigError, match="route.speed_kmh.s-curve"):
        gym.make("Bogie/HuntingRoute-v1", config={"route": {"speed_kmh": {"s-curve": [900, 950]}}})
    with pytest.raises(ConfigError, match="route.names"):
        gym.make("Bogie/HuntingRoute-v1", config={"route": {"names": ["nowhere"]}})
    with pytest.raises(ConfigError, match="wear_weight"):
        gym.make("Bogie/Hunting-v1", config={"reward": {"wear_weight": 0.1}})


def test_left_and_right_curves_give_mirrored_curving_quantities(tmp_path):
    """Passive bogie, no irregularity, no perturbation: a right-hand curve mirrors a left one."""
    runs = {}
    for direction in ("left", "right"):
        path = _route_file(tmp_path, direction)
        env = gym.make("Bogie/HuntingRoutePassive-v1", config={**QUIET, "route": {"names": [path], "speed_kmh": {path: 160.0}}})
        env.reset(seed=1)
        runs[direction] = _run(env)
    (left, rew_left), (right, rew_right) = runs["left"], runs["right"]
    assert len(left) == len(right) > 300
    get = lambda infos, key: np.array([info[key] for info in infos])  # noqa: E731
    assert np.max(get(left, "wear_number_n")) > 1.0  # the curve is felt
    np.testing.assert_allclose(get(right, "wear_number_n"), get(left, "wear_number_n"), rtol=1e-7, atol=1e-9)
    np.testing.assert_array_equal(get(right, "flange_contact"), get(left, "flange_contact"))
    np.testing.assert_allclose(get(right, "y_over_q"), get(left, "y_over_q"), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(get(right, "guiding_force_n"), -get(left, "guiding_force_n"), rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(get(right, "curvature_1pm"), -get(left, "curvature_1pm"), rtol=1e-12)
    np.testing.assert_allclose(get(right, "cant_deficiency_m"), get(left, "cant_deficiency_m"), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rew_right, rew_left, rtol=1e-7, atol=1e-12)


def test_a_route_without_curvature_is_hunting_v1_on_straight_track(tmp_path):
    """A tangent-only route with the curving terms off steps bit for bit like Hunting-v1 at the
    same constant speed, position and actions."""
    path = _route_file(tmp_path, curvature=False)
    common = {"randomize": {}, "sensors": {"enabled": False}}
    route_env = gym.make("Bogie/HuntingRoute-v1", config={
        **common, "route": {"names": [path], "speed_kmh": {path: 250.0}},
        "reward": {"lateral_weight": 0.5, "yaw_weight": 0.2, "effort_weight": 0.2, "wear_weight": 0.0, "flange_weight": 0.0},
        "hunting": {"detrend_m": None}, "curving": {"y_over_q_limit": None}})  # fmt: skip
    straight_env = gym.make("Bogie/Hunting-v1", config={**common, "speed": {"start_kmh": 250.0, "end_kmh": 250.0, "accel": 0.0},
                                                        "reward": {"time_weight": 5.4}})  # fmt: skip
    route_env.reset(seed=0)
    straight_env.reset(seed=0)
    a, b = route_env.unwrapped.task, straight_env.unwrapped.task
    assert a.n_sub == b.n_sub
    x0 = a.states[0].copy()
    x0[state_index("y1")] += 2e-3
    for task in (a, b):  # the same start: state and position on the alignment
        task.sim.set_rows(0, x0, 250.0 / 3.6, 0.0, 100.0, end_speed=250.0 / 3.6)
    actions = np.random.default_rng(3).uniform(-1, 1, (150,) + route_env.action_space.shape)
    for action in actions:
        _, r1, t1, _, _ = route_env.step(action)
        _, r2, t2, _, _ = straight_env.step(action)
        np.testing.assert_array_equal(a.states, b.states)
        assert r1 == r2 and t1 == t2
    assert np.all(a.sim.track_sample[0, CURVATURE_WHEELSET1:] == 0.0)


def _wear_numbers_numpy(x, speed, samples, p):
    """Tγ per wheelset from the state, written out here (docs/model.md Eqs. 26-30 with the curving
    creepage terms of Eq. C5), not through the compiled contact functions."""
    out = []
    for i, (y, dy, psi, dpsi, phi, dphi) in enumerate(
        ((x[8 * i], x[8 * i + 1], x[8 * i + 4], x[8 * i + 5], x[8 * i + 6], x[8 * i + 7]) for i in range(2))
    ):
        y_rel = y - samples[ALIGNMENT_WHEELSET1 + i]
        kappa = samples[CURVATURE_WHEELSET1 + i]
        e, r0, lam = p[P_E], p[P_R0], p[P_LAM]
        xi_x = np.array([-lam * y_rel / r0 - e * (dpsi / speed + kappa), lam * y_rel / r0 + e * (dpsi / speed + kappa)])
        radii = np.array([r0 + lam * y_rel, r0 - lam * y_rel])
        xi_y = (dy + radii * dphi) / speed - psi
        xi_sp = dpsi / speed + np.array([-lam / r0, lam / r0]) + kappa
        fx = -p[P_F33] * xi_x
        fy = -p[P_F11] * xi_y - p[P_F12] * xi_sp
        beta = np.mean(np.hypot(fx, fy)) / (p[P_MU] * 0.5 * p[P_WPA])
        alpha = 1 - beta / 3 + beta**2 / 27 if beta <= 3 else 1 / beta
        out.append(-alpha * np.sum(fx * xi_x + fy * xi_y))
    return np.array(out)


def test_the_rewards_wear_term_matches_an_independent_evaluation(tmp_path):
    """Only the wear term on: reward = time_weight dt (1 - w min(mean Tγ / ref, 1))."""
    path = _route_file(tmp_path, "right")
    w, ref, time_weight = 0.5, 1e4, 5.4
    env = gym.make("Bogie/HuntingRoutePassive-v1", config={
        "route": {"names": [path], "speed_kmh": {path: 160.0}},
        "reward": {"lateral_weight": 0.0, "yaw_weight": 0.0, "effort_weight": 0.0, "wear_weight": w, "flange_weight": 0.0,
                   "wear_reference": ref, "time_weight": time_weight}})  # fmt: skip
    env.reset(seed=2)
    task = env.unwrapped.task
    checked = 0
    for _ in range(40):
        _, rewards = _run(env, steps=10)
        oracle = _wear_numbers_numpy(task.states[0], task.sim.speed[0], task.sim.track_sample[0], task.P[0])
        np.testing.assert_allclose(task.wear_number_n[0], oracle, rtol=1e-9, atol=1e-9)
        expected = time_weight * 0.01 * (1 - w * min(oracle.mean() / ref, 1.0))
        assert rewards[-1] == pytest.approx(expected, rel=1e-9)
        checked += abs(task.curvature_1pm[0]) > 0
    assert checked > 10  # most checks inside the curve or its transitions
