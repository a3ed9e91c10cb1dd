"""The env's input: absurd reset options and configs are named errors at construction, the
batch size is capped, stepping needs a reset; the vector and SB3 front-ends' reset, render
and attribute conventions."""

import numpy as np
import pytest

from bogie_env.params import ConfigError


def test_negative_reset_accel_is_rejected():
    from bogie_env.envs.hunting_env import BogieHuntingEnv

    env = BogieHuntingEnv()
    with pytest.raises(ConfigError, match=r"reset option 'accel' = -5 is not allowed; allowed: \[0, 10\]"):
        env.reset(seed=0, options={"accel": -5})
    with pytest.raises(ConfigError, match="reset option 'accel' = 1e\\+09 is not allowed"):
        env.reset(seed=0, options={"accel": 1e9})


@pytest.mark.parametrize(
    "config, message",
    [({"actuators": {"frame_lateral": {"bandwidth_hz": 0}}}, r"'actuators.frame_lateral.bandwidth_hz' = 0 is not allowed; allowed: \(0"),
     ({"actuators": {"frame_yaw": {"mode": "semi_active", "c_max": 1e8}}}, "c_max' = 100000000.0 is not allowed.*smaller substeps"),
     ({"randomize": {"lam": [0.5, 100.0]}}, r"'randomize.lam' = \[0.5, 100\]: the scale 100 gives an invalid bogie .*'lam'"),
     ({"randomize": {"Kpx": [1.0, 50.0]}}, r"'randomize.Kpx' = \[1, 50\]: the scale 50"),
     ({"speed": {"accel": -5}}, "'speed.accel' = -5 is not allowed")],
)  # fmt: skip
def test_env_config_rejected_at_construction(config, message):
    from bogie_env.envs.hunting_env import BogieHuntingEnv

    with pytest.raises(ConfigError, match=message):
        BogieHuntingEnv(config=config)


def test_num_envs_is_capped():
    from bogie_env.envs.config import MAX_NUM_ENVS
    from bogie_env.envs.vector import BogieHuntingVectorEnv

    with pytest.raises(ConfigError, match=f"num_envs = 1000000 is not allowed; allowed: an integer in \\[1, {MAX_NUM_ENVS}\\]"):
        BogieHuntingVectorEnv(10**6)


def test_stepping_before_reset_raises_reset_needed():
    import gymnasium as gym

    from bogie_env.envs.hunting_env import BogieHuntingEnv

    env = BogieHuntingEnv()
    with pytest.raises(gym.error.ResetNeeded):
        env.step(env.action_space.sample())
    env.reset(seed=0)
    obs, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    assert np.all(np.isfinite(obs))
    vec = gym.make_vec("Bogie/Hunting-v0", num_envs=3, vectorization_mode="vector_entry_point")
    with pytest.raises(gym.error.ResetNeeded):
        vec.step(vec.action_space.sample())
    vec.reset(seed=0, options={"reset_mask": np.array([True, False, True])})
    with pytest.raises(gym.error.ResetNeeded, match=r"env\(s\) \[1\]"):
        vec.step(vec.action_space.sample())


def test_vector_reset_takes_a_list_of_seeds():
    import gymnasium as gym

    vec = gym.make_vec("Bogie/Hunting-v0", num_envs=3, vectorization_mode="vector_entry_point")
    by_list, _ = vec.reset(seed=[5, 7, 5])
    by_int, _ = vec.reset(seed=5)  # env i gets 5 + i
    assert np.array_equal(by_list[0], by_list[2]) and np.array_equal(by_list[0], by_int[0])
    assert np.array_equal(by_list[1], by_int[2])
    with pytest.raises(ValueError, match="got 2 seeds for 3 environments"):
        vec.reset(seed=[1, 2])


def test_render_fps_is_one_over_dt():
    import gymnasium as gym

    from bogie_env.envs.hunting_env import BogieHuntingEnv

    assert BogieHuntingEnv().metadata["render_fps"] == 100
    assert BogieHuntingEnv(config={"dt": 0.02}).metadata["render_fps"] == 50
    vec = gym.make_vec("Bogie/Hunting-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert vec.metadata["render_fps"] == 100


def test_sb3_set_attr_and_env_method_honour_indices():
    from bogie_agents.training.vec_env import BogieHuntingSB3VecEnv

    venv = BogieHuntingSB3VecEnv(3, seed=0)
    venv.reset()
    venv.set_attr("difficulty", 2.0, indices=[1])
    assert venv.get_attr("difficulty", indices=[1]) == [2.0]
    with pytest.raises(AttributeError):
        venv.get_attr("difficulty", indices=[0])
    assert not hasattr(venv, "difficulty")  # not the VecEnv's own attribute
    venv.set_attr("config", venv.task.config)  # a task attribute: all sub-envs at once
    with pytest.raises(ValueError, match="set it without indices"):
        venv.set_attr("config", {}, indices=[0])
    before = venv.task.obs.copy()
    venv.task.sim.x[:] += 1e-3
    out = venv.env_method("observe", indices=[2])
    assert len(out) == 1
    after = venv.task.obs
    assert np.array_equal(after[:2], before[:2]) and not np.array_equal(after[2], before[2])
    with pytest.raises(IndexError):
        venv.env_method("observe", indices=[5])
