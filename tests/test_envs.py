"""The environments: API checks, determinism, agreement of the three front-ends, actuator
physics, bad input and rendering."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from bogie_agents.training.vec_env import BogieHuntingSB3VecEnv
import bogie_env  # noqa: F401  (registers the ids)
from bogie_env.envs.config import make_config
from bogie_env.envs.hunting_env import BogieHuntingEnv
from bogie_env.envs.task import HuntingTask
from bogie_env.envs.vector import BogieHuntingVectorEnv
from bogie_env.params import ConfigError
from bogie_env.simulator import PARALLEL_MIN_ROWS
from bogie_env.stability import critical_speed

SHORT = {"speed": {"start_kmh": 300.0, "end_kmh": 306.0, "accel": 5.0}}  # 0.33 s episodes


@pytest.mark.parametrize("env_id", ["Bogie/Hunting-v0", "Bogie/HuntingPassive-v0", "Bogie/HuntingSemiActive-v0"])
def test_gymnasium_and_sb3_checkers(env_id):
    env = gym.make(env_id)
    gym_check_env(env.unwrapped)
    sb3_check_env(gym.make(env_id).unwrapped)


def test_state_observation_passes_checkers():
    gym_check_env(BogieHuntingEnv(observation={"type": "state", "noise": 0.01, "include_actuators": True}))


def test_make_and_make_vec_by_id():
    env = gym.make("bogie_env:Bogie/Hunting-v0")
    assert env.unwrapped.max_episode_steps > 8000  # the env's own limit: the ramp's length + 10 %
    venv = gym.make_vec("bogie_env:Bogie/Hunting-v0", num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(venv, BogieHuntingVectorEnv) and venv.max_episode_steps == env.unwrapped.max_episode_steps
    obs, info = venv.reset(seed=1)
    assert obs.shape == (3, 11) and info["_speed_kmh"].all()


def test_seed_determinism():
    a, b = BogieHuntingEnv(), BogieHuntingEnv()
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    assert np.array_equal(oa, ob)
    rng = np.random.default_rng(0)
    for _ in range(200):
        act = rng.uniform(-1, 1, 4).astype(np.float32)
        assert np.array_equal(a.step(act)[0], b.step(act)[0])
    oc, _ = BogieHuntingEnv().reset(seed=8)
    assert not np.array_equal(oa, oc)


def test_single_vector_and_sb3_envs_give_identical_trajectories():
    """Through several episode ends: single envs reset by hand must match the Gymnasium
    vector env (NEXT_STEP autoreset: the reset takes the next step) and the SB3 VecEnv
    (same-step reset, last observation in ``terminal_observation``)."""
    n, seed = 3, 11
    for_vec = [BogieHuntingEnv(SHORT) for _ in range(n)]
    for_sb3 = [BogieHuntingEnv(SHORT) for _ in range(n)]
    first = [e.reset(seed=seed + i)[0] for i, e in enumerate(for_vec)]
    for i, e in enumerate(for_sb3):
        e.reset(seed=seed + i)
    vec = BogieHuntingVectorEnv(n, SHORT)
    vobs, _ = vec.reset(seed=seed)
    sb3 = BogieHuntingSB3VecEnv(n, SHORT, seed=seed)
    bobs = sb3.reset()
    assert np.array_equal(np.array(first), vobs) and np.array_equal(vobs, bobs)
    rng = np.random.default_rng(5)
    pending_reset = np.zeros(n, dtype=bool)
    ends = 0
    for _ in range(120):
        actions = rng.uniform(-1, 1, (n, 4)).astype(np.float32)
        vobs, vrew, vterm, vtrunc, _ = vec.step(actions)
        sb3.step_async(actions)
        bobs, brew, bdone, binfo = sb3.step_wait()
        for i in range(n):
            if pending_reset[i]:
                obs, _ = for_vec[i].reset()
                assert np.array_equal(obs, vobs[i]) and vrew[i] == 0.0 and not (vterm[i] or vtrunc[i])
                pending_reset[i] = False
            else:
                obs, rew, term, trunc, _ = for_vec[i].step(actions[i])
                assert np.array_equal(obs, vobs[i]) and rew == vrew[i] and (term, trunc) == (vterm[i], vtrunc[i])
                pending_reset[i] = term or trunc
            obs, rew, term, trunc, _ = for_sb3[i].step(actions[i])
            assert np.float32(rew) == brew[i] and bdone[i] == (term or trunc)
            if term or trunc:
                assert np.array_equal(binfo[i]["terminal_observation"], obs)
                assert binfo[i]["TimeLimit.truncated"] == (trunc and not term)
                obs, _ = for_sb3[i].reset()
                ends += 1
            assert np.array_equal(obs, bobs[i])
    assert ends >= 6


@pytest.mark.slow  # 5-10 s warm: make test stays within 3 minutes from a clean clone
def test_batch_size_does_not_change_a_rows_trajectory():
    """Rows are independent: a row of a 260-env batch (thread pool) follows exactly the 4-env
    batch's row (calling thread)."""
    n = 260
    assert n >= PARALLEL_MIN_ROWS
    small, large = HuntingTask(4), HuntingTask(n, num_threads=2)
    small.seed_rows(np.arange(4), list(range(4)))
    large.seed_rows(np.arange(n), [i % 4 for i in range(n)])
    small.reset_rows(np.arange(4))
    large.reset_rows(np.arange(n))
    rng = np.random.default_rng(1)
    for _ in range(100):
        a = rng.uniform(-1, 1, (4, 4))
        small.step(a)
        large.step(np.tile(a, (n // 4, 1)))
        assert np.array_equal(small.obs, large.obs[:4]) and np.array_equal(small.states, large.states[:4])
        assert np.array_equal(small.states, large.states[n - 4 :])
    assert not np.isnan(large.loops.seconds).any()  # both loops (calling thread, pool) ran


def test_bad_actions_are_errors_or_documented_clipping():
    env = BogieHuntingEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.array([0.0, np.nan, 0.0, 0.0], dtype=np.float32))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.array([np.inf, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"action has shape \(3,\); expected \(1, 4\) or \(4,\)"):
        env.step(np.zeros(3))
    assert np.all(np.isfinite(env.task.x))  # nothing was stepped
    clipped, big = BogieHuntingEnv(), BogieHuntingEnv()
    clipped.reset(seed=1)
    big.reset(seed=1)
    for _ in range(20):
        assert np.array_equal(clipped.step(np.ones(4))[0], big.step(np.full(4, 7.0))[0])
    venv = BogieHuntingVectorEnv(2)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"expected \(2, 4\)"):
        venv.step(np.zeros((3, 4)))


@pytest.mark.parametrize(
    "config, message",
    [
        ({"speed": {"accell": 1.0}}, "unknown config key 'speed.accell'; known keys at this level: start_kmh"),
        ({"dt": 0.001}, "'dt' = 0.001 is not allowed; allowed: \\[0.01, 0.1\\]"),
        ({"actuators": {"frame_yaw": {"mode": "magic"}}}, "'actuators.frame_yaw.mode' = 'magic' is not allowed"),
        ({"observation": {"type": "pixels"}}, "'observation.type' = 'pixels'"),
        ({"track": {"rms": -1.0}}, "'track.rms' = -1.0"),
        ({"randomize": {"Cxx": [0.5, 1.0]}}, "randomize.Cxx': unknown parameter"),
        ({"bogie_overrides": {"Csy": float("nan")}}, "'Csy' = nan"),
        ({"speed": {"start_kmh": 500.0, "end_kmh": 400.0}}, "must not be below"),
        ({"reward": {"lateral_weight": 0.6, "yaw_weight": 0.3, "effort_weight": 0.2}}, "sum to less than 1"),
        ({"wrong": 1}, "unknown config key 'wrong'"),
    ],
)
def test_bad_config_names_the_key(config, message):
    with pytest.raises(ConfigError, match=message):
        BogieHuntingEnv(config)


def test_reset_options_and_bad_options():
    env = BogieHuntingEnv({"speed": {"start_kmh_range": [250.0, 350.0]}})
    _, info = env.reset(seed=0, options={"start_kmh": 320.0, "params": {"Csy": 0.5}})
    assert info["speed_kmh"] == 320.0 and env.task.episode_params[0] == {"Csy": 0.5}
    with pytest.raises(ConfigError, match="unknown reset option"):
        env.reset(options={"speed": 3})
    with pytest.raises(ConfigError, match="must satisfy"):
        env.reset(options={"start_kmh": 100.0})


def test_parameter_randomisation_changes_the_bogie():
    env = BogieHuntingEnv({"randomize": {"Csy": [0.5, 0.6], "Wpa": [0.5, 1.5]}})
    seen = []
    for seed in range(5):
        env.reset(seed=seed)
        scales = env.task.episode_params[0]
        assert 0.5 <= scales["Csy"] <= 0.6 and 0.5 <= scales["Wpa"] <= 1.5
        seen.append(env.task.P[0].copy())
    assert len({row.tobytes() for row in seen}) == 5


def test_passive_env_ignores_actions_and_hunts_near_the_critical_speed():
    """Time domain against eigenvalues: the passive bogie's hunting onset on the 1 m/s^2 ramp
    lies just above the linear critical speed (the ramp delays it, the track noise advances it)."""
    linear = critical_speed().speed_kmh
    onsets = []
    for seed in range(3):
        a, b = BogieHuntingEnv({"actuators": {"frame_lateral": {"mode": "off"}, "frame_yaw": {"mode": "off"},
                                              "wheelset1_yaw": {"mode": "off"}, "wheelset2_yaw": {"mode": "off"}}}), \
            gym.make("Bogie/HuntingPassive-v0").unwrapped  # fmt: skip
        a.reset(seed=seed)
        b.reset(seed=seed)
        while True:
            oa, ra, ta, ua, ia = a.step(np.array([1.0], dtype=np.float32))
            ob, rb, tb, ub, ib = b.step(np.array([-1.0], dtype=np.float32))
            assert np.array_equal(oa, ob)
            if ta or ua:
                break
        assert ta and ia["hunting"]
        onsets.append(ia["onset_speed_kmh"])
    assert all(linear - 10.0 < v < linear + 25.0 for v in onsets), (linear, onsets)


def test_actuators_respect_limits_and_semi_active_only_dissipates():
    env = gym.make("Bogie/HuntingSemiActive-v0").unwrapped
    env.reset(seed=0)
    limits = env.task.actuator_limits
    rng = np.random.default_rng(0)
    for _ in range(3000):
        _, _, term, trunc, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
        assert np.all(np.abs(info["actuator_force"]) <= limits + 1e-9)
        assert np.all(info["actuator_power"] <= 1e-9)
        if term or trunc:
            env.reset()
    active = BogieHuntingEnv()
    active.reset(seed=0)
    for _ in range(300):
        _, _, _, _, info = active.step(np.ones(4, dtype=np.float32))
        assert np.all(np.abs(info["actuator_force"]) <= limits + 1e-9)
    # after 3 s of full command the 10 Hz lag has converged to the limit
    on = active.task.active_channels
    assert info["actuator_force"][on] == pytest.approx(limits[on], rel=1e-6)


def test_actuator_delay_shifts_the_response():
    delayed = BogieHuntingEnv({"actuators": {name: {"delay_steps": 3} for name in
                                             ("frame_lateral", "frame_yaw", "wheelset1_yaw", "wheelset2_yaw")}})  # fmt: skip
    delayed.reset(seed=0)
    forces = [delayed.step(np.ones(4, dtype=np.float32))[4]["actuator_force"][0] for _ in range(5)]
    assert forces[:3] == [0.0, 0.0, 0.0] and forces[3] > 0.0


def test_reward_pays_progress_and_grows_with_speed():
    env = BogieHuntingEnv()
    _, info = env.reset(seed=2)
    total, start = 0.0, info["speed_kmh"]
    while True:
        _, r, term, trunc, info = env.step(np.zeros(4, dtype=np.float32))
        assert 0.0 <= r <= 1.0 * 3.6 * env.config["speed"]["accel"] * env.config["dt"] + 1e-12
        total += r
        if term or trunc:
            break
    gained = info["speed_kmh"] - start
    assert 0.3 * gained < total <= gained + 1e-9


def test_vector_env_enforces_max_episode_steps():
    venv = BogieHuntingVectorEnv(2, max_episode_steps=5)
    venv.reset(seed=0)
    for k in range(5):
        _, _, term, trunc, _ = venv.step(np.zeros((2, 4)))
    assert trunc.all() and not term.any()
    obs, rew, term, trunc, _ = venv.step(np.zeros((2, 4)))  # NEXT_STEP: the reset step
    assert np.all(rew == 0) and not trunc.any()


def test_vector_env_reset_mask_resets_only_the_masked_envs():
    """Gymnasium's reset(options={"reset_mask": mask}): a masked env restarts exactly as a
    single env seeded the same way; the others keep their episodes."""
    venv = BogieHuntingVectorEnv(3)
    venv.reset(seed=7)
    for _ in range(20):
        venv.step(np.full((3, 4), 0.3))
    before = venv.task.states.copy()
    mask = np.array([False, True, False])
    obs, info = venv.reset(seed=100, options={"reset_mask": mask})
    single = BogieHuntingEnv()
    single_obs, _ = single.reset(seed=101)  # env i of a vector reset with seed s uses s + i
    assert np.array_equal(obs[1], single_obs) and info["speed_kmh"][1] == 300.0
    assert np.array_equal(venv.task.states[[0, 2]], before[[0, 2]])
    assert np.all(venv.task.speed_kmh[[0, 2]] > 300.0)
    for bad in (np.array([1, 0, 1]), np.ones(2, dtype=bool)):
        with pytest.raises(ValueError, match="reset_mask"):
            venv.reset(options={"reset_mask": bad})


def test_gymnasium_vector_wrappers_accept_the_env():
    from gymnasium.wrappers.vector import NormalizeObservation, RecordEpisodeStatistics

    venv = RecordEpisodeStatistics(NormalizeObservation(BogieHuntingVectorEnv(2, SHORT)))
    venv.reset(seed=0)
    finished = 0
    for _ in range(80):
        _, _, term, trunc, info = venv.step(np.zeros((2, 4), dtype=np.float32))
        if np.any(term | trunc):
            assert "episode" in info and np.all(info["episode"]["r"][term | trunc] > 0)
            finished += 1
    assert finished >= 1


def test_rgb_array_rendering(tmp_path):
    env = gym.make("Bogie/Hunting-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8 and frame.std() > 5
    for _ in range(10):
        env.step(env.action_space.sample())
    assert not np.array_equal(env.render(), frame)
    env.close()


def test_record_video(tmp_path):
    pytest.importorskip("moviepy")
    from gymnasium.wrappers import RecordVideo

    env = RecordVideo(gym.make("Bogie/Hunting-v0", config=SHORT, render_mode="rgb_array"), str(tmp_path),
                      episode_trigger=lambda k: True)  # fmt: skip
    env.reset(seed=0)
    done = False
    while not done:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        done = term or trunc
    env.close()
    assert list(tmp_path.glob("*.mp4"))


@pytest.mark.parametrize("channel, max_force, bandwidth_hz", [("frame_lateral", 7e3, 4.0), ("wheelset2_yaw", 12e3, 25.0)])
def test_a_channels_force_limit_and_bandwidth_reach_its_lag(channel, max_force, bandwidth_hz):
    """A held full command drives a channel's force along its first-order lag from the config:
    ``F_n = F_max (1 - exp(-2 pi f_c n dt))`` (exact: the lag is solved in closed form per
    step), with ``max_force`` in N (N m) and ``bandwidth_hz`` in Hz; the other channels stay at
    zero. (A limit or a corner frequency read from the wrong key, or in rad/s, fails this.)"""
    from bogie_env.actuators import CHANNEL_NAMES

    config = make_config({"actuators": {channel: {"max_force": max_force, "bandwidth_hz": bandwidth_hz}},
                          "track": {"rms": 0.0}, "initial_perturbation": 0.0})  # fmt: skip
    task = HuntingTask(1, config)
    task.seed_rows(np.array([0]), [0])
    task.reset_rows(np.array([0]))
    assert task.actuator_limits[task.channel_names.index(channel)] == max_force
    action = np.zeros((1, task.action_dim))
    action[0, task.channel_names.index(channel)] = 1.0
    k = CHANNEL_NAMES.index(channel)
    for n in range(1, 6):
        task.step(action)
        expected = max_force * (1.0 - math.exp(-2.0 * math.pi * bandwidth_hz * config["dt"] * n))
        assert task.actuator_force[0, k] == pytest.approx(expected, rel=1e-12)
        assert np.all(np.delete(task.actuator_force[0], k) == 0.0)


def test_sensors_read_what_they_name():
    """Each sensor against its definition from the states (and the right-hand side for the
    frame acceleration); the template for a new sensor's test (docs/extending.md)."""
    from bogie_env.actuators import force_matrix
    from bogie_env.dynamics import state_index as si
    from bogie_env.envs import task as T

    env = BogieHuntingEnv()
    env.reset(seed=5)
    for _ in range(30):
        obs, *_ = env.step(np.array([0.5, -0.3, 0.2, 0.1], dtype=np.float32))
    task = env.task
    x, v = task.states[0], task.speed_kmh[0] / 3.6
    p = task.model.params
    accel = task.model.rhs(x, v, inputs=force_matrix() @ task.actuator_force[0], track=task.sim.track_sample[0])
    expected = {
        T.SENSOR_FRAME_LATERAL_ACCEL: accel[si("dyb")] / T.ACCEL_SCALE,
        T.SENSOR_FRAME_YAW_RATE: x[si("dpsib")] / T.YAW_RATE_SCALE,
        T.SENSOR_WHEELSET1_LATERAL: (x[si("y1")] - x[si("yb")] - p.L1 * x[si("psib")]) / p.delta,
        T.SENSOR_WHEELSET2_LATERAL: (x[si("y2")] - x[si("yb")] + p.L1 * x[si("psib")]) / p.delta,
        T.SENSOR_WHEELSET1_YAW: (x[si("psi1")] - x[si("psib")]) / T.REL_YAW_SCALE,
        T.SENSOR_WHEELSET2_YAW: (x[si("psi2")] - x[si("psib")]) / T.REL_YAW_SCALE,
        T.speed_index("sensors"): (task.speed_kmh[0] - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH,
    }
    for index, value in expected.items():
        assert obs[index] == pytest.approx(np.clip(value, -10, 10), rel=1e-5, abs=1e-6), T.SENSORS[index] if index < 6 else "speed"
    active = task.active_channels
    assert np.allclose(obs[7:], task.actuator_force[0, active] / task.actuator_limits[active], rtol=1e-5)


@pytest.mark.parametrize("n", [3, PARALLEL_MIN_ROWS])
def test_a_non_finite_action_steps_nothing_on_either_loop(n):
    task = HuntingTask(n, num_threads=2)
    task.seed_rows(np.arange(n), list(range(n)))
    task.reset_rows(np.arange(n))
    before = task.states.copy()
    actions = np.zeros((n, 4), dtype=np.float32)
    actions[n - 2, 3] = np.nan
    with pytest.raises(ValueError, match=f"env {n - 2}, component 3"):
        task.step(actions)
    assert np.array_equal(task.states, before)
    actions[n - 2, 3] = 7.0  # clipped to 1
    task.step(actions)
    assert task.actions[n - 2, 3] == 1.0
