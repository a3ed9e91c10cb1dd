"""Distillation of the privileged reference (agents/training/distill.py, agents/controllers/distilled.py):
the batched teacher labels exactly as the privileged controller acts, the student sees in training
exactly what it sees at evaluation, its files load without trust, and bad configs name the key."""

import dataclasses
import json

import numpy as np
import pytest

from bogie_agents.controllers.distilled import META_FILE, DistilledPolicy, StudentNetwork, load_student, save_student
from bogie_agents.controllers.policies import load_policy
from bogie_agents.controllers.privileged import PrivilegedController
from bogie_agents.design.margins import check_controller_model
from bogie_agents.training.distill import (Rollouts, TeacherBank, bank_config, distill, draw_bank, env_config, frame_statistics,
                                           load_config, mirror_signs, route_env_config, scenario_options,
                                           state_observation)
from bogie_env.envs.config import merge_config
from bogie_env.params import ConfigError
from bogie_env.envs.task import HuntingTask
from bogie_env.params import ConfigError

SHORT = {"speed": {"start_kmh_range": [180.0, 200.0], "end_kmh": 260.0, "accel": 2.0}, "large_perturbation_probability": 1.0}


def _cfg(**changes):
    return load_config(None, {"env": SHORT, "n_envs": 2, **changes})


@pytest.fixture(scope="module")
def bank_and_teacher():
    cfg = _cfg()
    env_cfg = env_config(cfg)
    bank = [dataclasses.replace(s, conicity=lam) for s, lam in zip(draw_bank(env_cfg, 2, 7, {"actuator_failure_probability": 0.0}), (0.05, 0.3))]
    assert bank[0].primary_longitudinal_stiffness != 1.0  # the env's other draws stay in the bank
    return env_cfg, bank, TeacherBank(env_cfg, bank)


def test_scenario_options_reproduce_the_scenario(bank_and_teacher):
    env_cfg, bank, _ = bank_and_teacher
    task = HuntingTask(2, env_cfg)
    task.seed_rows(np.arange(2), [123, 456])  # other draws than the bank's: the options must override them
    for i, s in enumerate(bank):
        task.reset_rows(np.array([i]), scenario_options(s))
        assert task.scenarios[i].as_dict() == s.as_dict()


def _bank_rows_and_references(task_cfg, env_cfg, bank):
    """A task whose row i runs bank scenario i, and a PrivilegedController told each row's scenario."""
    task = HuntingTask(len(bank), task_cfg)
    task.seed_rows(np.arange(len(bank)), [1 + i for i in range(len(bank))])
    for i, s in enumerate(bank):
        task.reset_rows(np.array([i]), scenario_options(s))
    controllers = [PrivilegedController(env_cfg).tell(s, env_cfg) for s in bank]
    for c in controllers:
        c.reset(1)
    return task, controllers


def test_teacher_bank_labels_as_the_privileged_controller_acts(bank_and_teacher):
    """Row i of the bank's teacher gives, step after step, the command of a PrivilegedController
    told row i's scenario and fed the env's own full-state observation, which the teacher's
    state_observation reproduces bit for bit from the sensor task's states."""
    env_cfg, bank, teacher = bank_and_teacher
    state_cfg = merge_config(env_cfg, {"observation": {"type": "state"}, "sensors": {"enabled": False}})
    task, controllers = _bank_rows_and_references(state_cfg, env_cfg, bank)
    teacher.reset(2, np.arange(2), np.arange(2))
    for _ in range(60):
        labels = teacher.command(state_observation(task))
        np.testing.assert_array_equal(state_observation(task), task.obs[:, :21])  # then the actuator forces
        acts = np.concatenate([c.act(task.obs[i : i + 1]) for i, c in enumerate(controllers)])
        np.testing.assert_array_equal(labels.astype(np.float32), acts)
        task.step(labels)
        teacher.advance(labels)
    assert np.abs(labels).max() > 1e-3  # the check saw real commands


def test_mpc_teacher_bank_labels_as_the_mpc_reference_acts(bank_and_teacher):
    """The same for ``teacher: privileged_mpc``: row i's label is the command of an MPCReference
    told row i's scenario (its own QPs; the loop states and warm starts the bank's rows')."""
    from bogie_agents.controllers.mpc import MPCReference
    from bogie_agents.training.distill import MPCTeacherBank

    env_cfg, bank, _ = bank_and_teacher
    teacher = MPCTeacherBank(env_cfg, bank)
    state_cfg = merge_config(env_cfg, {"observation": {"type": "state"}, "sensors": {"enabled": False}})
    controllers = [MPCReference(env_cfg).tell(s, env_cfg) for s in bank]
    for c in controllers:
        c.reset(1)
    teacher.reset(2, np.arange(2), np.array([1, 0]))  # row i runs scenario 1 - i: the rows' designs are looked up
    task = HuntingTask(2, state_cfg)
    task.seed_rows(np.arange(2), [1, 2])
    for i, s in enumerate(bank[::-1]):
        task.reset_rows(np.array([i]), scenario_options(s))
    active = 0
    for _ in range(40):
        labels = teacher.command(state_observation(task))
        acts = np.concatenate([c.act(task.obs[i : i + 1]) for i, c in enumerate(controllers[::-1])])
        np.testing.assert_array_equal(labels.astype(np.float32), acts)
        active += int(np.any(np.abs(labels) >= 1.0 - 1e-9))
        task.step(labels)
        teacher.advance(labels)
    assert np.abs(labels).max() > 1e-3 and active > 0  # real commands, and the force limit was met
    assert teacher.loop.fallbacks == 0


def test_training_inputs_are_what_the_saved_student_sees(tmp_path, bank_and_teacher):
    """The student driving the rollouts (beta 0) and the same student saved, loaded and fed the
    rollout's observations see the same inputs and send the same commands: no train/evaluation skew."""
    env_cfg, bank, teacher = bank_and_teacher
    rng = np.random.default_rng(0)
    history, obs_dim, action_dim = 3, 11, 4
    frame = obs_dim + action_dim
    sizes = [history * frame, 8, action_dim]
    network = StudentNetwork([rng.normal(0, 0.5, (sizes[i + 1], sizes[i])) for i in range(2)],
                             [rng.normal(0, 0.1, sizes[i + 1]) for i in range(2)],
                             np.zeros(sizes[0]), np.ones(sizes[0]))  # fmt: skip
    roll = Rollouts(env_cfg, 2, bank, teacher, history, seed=5)
    steps = 40
    inputs, _, _ = roll.run(steps, network, beta=0.0)
    assert not roll.by_teacher.any() and not roll.task.done.any()
    inputs = inputs.reshape(steps, 2, history, frame)
    save_student(tmp_path / "s", network, history, obs_dim, action_dim, {"env_id": "Bogie/Hunting-v1"})
    student = load_policy(str(tmp_path / "s"), env_cfg)  # plain arrays: no trust needed
    student.reset(2)
    for t in range(steps):
        u = student.act(inputs[t, :, -1, :obs_dim])
        np.testing.assert_array_equal(student.frames.frames, inputs[t])
        if t + 1 < steps:
            np.testing.assert_array_equal(u, inputs[t + 1, :, -1, obs_dim:])
    assert np.abs(inputs[1:, :, -1, obs_dim:]).max() > 1e-2  # the student did command something


def test_student_files_are_checked(tmp_path):
    network = StudentNetwork([np.zeros((4, 30))], [np.zeros(4)], np.zeros(30), np.ones(30))
    save_student(tmp_path, network, 2, 11, 4, {})
    assert load_student(tmp_path).act(np.zeros((3, 11))).shape == (3, 4)
    meta = json.loads((tmp_path / META_FILE).read_text())
    meta["history"] = 3
    (tmp_path / META_FILE).write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"layer 0 has weights \(4, 30\)"):
        load_student(tmp_path)
    meta["history"], meta["layers"] = 2, 2
    (tmp_path / META_FILE).write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"arrays \['w1', 'b1'\] are missing"):
        load_student(tmp_path)


@pytest.mark.parametrize("changes, match", [({"n_envs": 0}, "'n_envs' = 0"), ({"dagger": {"beta0": 2}}, "dagger.beta0"),
                                            ({"dagger": {"betta": 1}}, "dagger.betta"), ({"env_id": "Bogie/Nope-v1"}, "env_id"),
                                            ({"student": {"hidden": []}}, "student.hidden"), ({"dagger": {"beta0": True}}, "dagger.beta0"),
                                            ({"fit": {"learning_rate": -1}}, "fit.learning_rate"),
                                            ({"teacher": "mpc"}, "'teacher' = 'mpc'; allowed: one of privileged, privileged_mpc"),
                                            ({"routes": {"n_envs": -1}}, "'routes.n_envs' = -1"),
                                            ({"routes": {"env_id": "Bogie/Nope-v1"}}, "'routes.env_id'"),
                                            ({"routes": {"rows": 2}}, "'routes' = ")])  # fmt: skip
def test_bad_config_names_the_key(changes, match):
    with pytest.raises(ConfigError, match=match):
        load_config(None, changes)


def test_shipped_distill_configs_load():
    """Every configs/agents/distill*.yaml passes the config's checks (an unknown key names itself)."""
    from pathlib import Path

    paths = sorted((Path(__file__).resolve().parents[1] / "configs" / "agents").glob("distill*.yaml"))
    assert len(paths) >= 4
    teachers = {load_config(p)["teacher"] for p in paths}
    assert teachers == {"privileged", "privileged_mpc"}


@pytest.mark.slow  # 10-30 s: torch's import and fit
@pytest.mark.parametrize("student, penalty", [({"history": 2, "hidden": [16]}, None),
                                              ({"history": 2, "hidden": [16], "residual": {"baseline": "robust_steering"}},
                                               {"points": [[250.0, 0.1]], "every": 5, "horizon_log2": 8})])  # fmt: skip
def test_distill_writes_a_student_that_moves_toward_the_teacher(tmp_path, student, penalty):
    cfg = _cfg(bank={"size": 2}, dagger={"iterations": 2, "steps": 150}, student=student,
               fit={"epochs": 20, "batch_size": 64, "loop_penalty": penalty})  # fmt: skip
    out = distill(cfg, tmp_path / "run", progress=False)
    progress = json.loads((out / "progress.json").read_text())["iterations"]
    assert [p["iteration"] for p in progress] == [0, 1]
    assert progress[-1]["loss"] < 0.5 * progress[-1]["label_variance"]  # it explains most of the teacher's commands
    assert load_student(out).frames.history == 2
    assert (progress[-1]["growth_bound_max_per_s"] is None) == (penalty is None)


@pytest.mark.slow  # about 20 s: two teachers, torch's import and fit
def test_route_rows_run_the_shipped_routes_beside_the_main_rows(tmp_path):
    """``routes.n_envs`` rows run ``Bogie/HuntingRoute-v1``'s routes on the same bank, labelled by
    their own teacher; their samples join the main rows' in every iteration, and none without them."""
    cfg = _cfg(bank={"size": 2}, dagger={"iterations": 1, "steps": 40, "keep_every": 2}, student={"history": 2, "hidden": [8]},
               fit={"epochs": 1, "batch_size": 64}, routes={"n_envs": 3})  # fmt: skip
    assert route_env_config(cfg)["route"]["names"] and route_env_config(_cfg()) is None
    out = distill(cfg, tmp_path / "run", progress=False)
    progress = json.loads((out / "progress.json").read_text())["iterations"]
    assert progress[0]["samples"] == (2 + 3) * 40 // 2
    assert json.loads((out / META_FILE).read_text())["config"]["routes"]["n_envs"] == 3


def _random_student(history=4, obs_dim=11, action_dim=4, scale=0.15, seed=3):
    rng = np.random.default_rng(seed)
    sizes = [history * (obs_dim + action_dim), 16, action_dim]
    network = StudentNetwork([rng.normal(0, scale, (sizes[i + 1], sizes[i])) for i in range(2)],
                             [rng.normal(0, 0.05, sizes[i + 1]) for i in range(2)],
                             rng.normal(0, 0.1, sizes[0]), np.full(sizes[0], 0.5))  # fmt: skip
    return DistilledPolicy(network, history, obs_dim, action_dim)


def test_student_linear_model_follows_act():
    """The margins' model of a student (frames and its own last command as states) follows act on
    a random observation sequence; with the command feedback cut it does not."""
    policy = _random_student()
    y0 = np.random.default_rng(1).normal(0, 0.3, 11)
    ctrl = policy.controller_model(11, 300.0, y0)
    ctrl.check_shapes(11, 4)
    assert ctrl.n_states == 3 * 15 + 4
    u0 = policy.act(y0[None].astype(np.float32))[0].astype(float)
    assert check_controller_model(policy, ctrl, y0, u0, steps=12) < 2e-2
    cut = dataclasses.replace(ctrl, a=ctrl.a.copy())
    cut.a[:, -4:] = 0.0  # the last command no longer enters the frames
    assert check_controller_model(policy, cut, y0, u0, steps=12) > 0.1


def test_episode_steps_restart_rows_on_a_new_bank_scenario(bank_and_teacher):
    env_cfg, bank, teacher = bank_and_teacher
    roll = Rollouts(env_cfg, 2, bank, teacher, 2, seed=1, episode_steps=5)
    _, labels, info = roll.run(12, None, beta=1.0)
    assert info["episodes"] == 4  # each row restarted after steps 5 and 10
    assert roll.steps.tolist() == [2, 2]
    with pytest.raises(ConfigError, match="'episode_steps' = 0"):
        load_config(None, {"episode_steps": 0})


def test_a_mirrored_student_is_odd_and_its_jacobian_is_exact():
    """With a mirror mask the student commands nothing at rest and the opposite for the mirrored
    input at any speed; its Jacobian matches central differences (float64)."""
    rng = np.random.default_rng(4)
    base = _random_student(history=2)
    mirror = -np.ones(30)
    mirror[[6, 21]] = 1.0  # the speed entry of each frame
    mean = np.where(mirror < 0, 0.0, base.network.mean)
    net = StudentNetwork(base.network.weights, base.network.biases, mean, base.network.std, mirror)
    x = rng.normal(0, 0.5, 30)
    flipped = x * mirror
    np.testing.assert_allclose(net.forward(x[None], np.float64), -net.forward(flipped[None], np.float64), atol=1e-12)
    rest = np.where(mirror < 0, 0.0, x)
    np.testing.assert_allclose(net.forward(rest[None], np.float64), 0.0, atol=1e-12)
    step = 1e-6
    numeric = np.stack([(net.forward((x + step * e)[None], np.float64)[0] - net.forward((x - step * e)[None], np.float64)[0])
                        / (2 * step) for e in np.eye(30)], axis=1)  # fmt: skip
    np.testing.assert_allclose(net.jacobian(x), numeric, atol=1e-7)


def test_a_bank_with_parameter_factors_runs_the_bogie_the_teacher_is_designed_for():
    env_cfg = env_config(_cfg())
    bank = draw_bank(env_cfg, 2, 3, {"Csy": [0.3, 0.6]})
    assert all(0.3 <= s.factors["Csy"] <= 0.6 for s in bank)
    task = HuntingTask(2, bank_config(env_cfg, {"Csy": [0.3, 0.6]}))
    task.seed_rows(np.arange(2), [11, 12])
    for i, s in enumerate(bank):
        task.reset_rows(np.array([i]), scenario_options(s))
        assert task.scenarios[i].as_dict() == s.as_dict()


@pytest.mark.slow  # 2.4-6 s warm: make test's 3 minutes on a clean clone
def test_teacher_registers_follow_the_commands_sent_not_its_own(bank_and_teacher):
    """Driven by random commands, the bank's labels stay those of PrivilegedControllers whose loop
    states advance with the same commands; advanced with their own labels instead, they differ."""
    env_cfg, bank, teacher = bank_and_teacher
    task, controllers = _bank_rows_and_references(env_cfg, env_cfg, bank)
    wrong = TeacherBank(env_cfg, bank)
    teacher.reset(2, np.arange(2), np.arange(2))
    wrong.reset(2, np.arange(2), np.arange(2))
    rng = np.random.default_rng(2)
    gap = 0.0
    for _ in range(30):
        obs = state_observation(task)
        labels = teacher.command(obs)
        expected = np.concatenate([c.command(c.state_estimate(obs[i : i + 1]), c.gain_at(c.speed_kmh(obs[i : i + 1])))
                                   for i, c in enumerate(controllers)])  # fmt: skip
        np.testing.assert_array_equal(labels, expected)
        gap = max(gap, float(np.abs(wrong.command(obs) - labels).max()))
        sent = rng.uniform(-1, 1, (2, 4))
        task.step(sent)
        teacher.advance(sent)
        wrong.advance(wrong.command(obs))
        for i, c in enumerate(controllers):
            c.advance(sent[i : i + 1])
    assert gap > 1e-2


def test_keep_every_keeps_every_kth_sample_of_the_same_run(bank_and_teacher):
    env_cfg, bank, teacher = bank_and_teacher
    every = Rollouts(env_cfg, 2, bank, teacher, 2, seed=9).run(6, None, 1.0, keep_every=1)
    second = Rollouts(env_cfg, 2, bank, teacher, 2, seed=9).run(6, None, 1.0, keep_every=2)
    for a, b in zip(every[:2], second[:2]):
        np.testing.assert_array_equal(a.reshape(6, 2, -1)[::2], b.reshape(3, 2, -1))


def test_mirror_signs_and_statistics(bank_and_teacher):
    env_cfg, bank, teacher = bank_and_teacher
    task = HuntingTask(1, env_cfg)
    mirror = mirror_signs(task, 2)
    assert mirror.shape == (30,) and np.flatnonzero(mirror > 0).tolist() == [6, 21]  # the speed entries
    x = np.random.default_rng(0).normal(1.0, 0.5, (500, 30)).astype(np.float32)
    mean, std = frame_statistics(x, 2, mirror)
    assert np.all(mean[mirror < 0] == 0.0) and np.all(mean[mirror > 0] != 0.0)
    np.testing.assert_allclose(std[0], np.sqrt(np.mean(x[:, 15].astype(float) ** 2)), rtol=1e-5)  # RMS about zero


# ---- a student on a classical baseline (student.residual) ---------------------------------------
RESIDUAL = {"baseline": "robust_steering", "scale": 0.5}


def _residual_student(env_cfg, history=3, seed=6, weight=0.4):
    """A random mirror-odd correction on robust_steering (bias-free: odd with or without the mask)."""
    from bogie_agents.controllers.distilled import ResidualFrames

    frames = ResidualFrames(history, env_cfg, RESIDUAL["baseline"], RESIDUAL["scale"], 4)
    rng = np.random.default_rng(seed)
    n_in = history * frames.frame_dim
    mirror = np.tile(frames.mirror_frame(), history)
    std = np.where(mirror < 0, 1.0, 0.5).astype(np.float32)
    network = StudentNetwork([rng.normal(0, weight, (16, n_in)), rng.normal(0, weight, (4, 16))], [np.zeros(16), np.zeros(4)],
                             np.where(mirror < 0, 0.0, 0.2), std, mirror)  # fmt: skip
    return DistilledPolicy(network, history, frames.obs_dim, 4, frames=frames), frames


def test_a_residual_student_is_its_baseline_at_rest_and_not_when_the_sensors_move(bank_and_teacher):
    from bogie_agents.controllers.classical import CLASSICAL

    env_cfg = bank_and_teacher[0]
    policy, _ = _residual_student(env_cfg)
    baseline = CLASSICAL[RESIDUAL["baseline"]](env_cfg)
    from bogie_env.envs import task as T

    rng = np.random.default_rng(1)
    y_rest = np.tile(rng.normal(0, 0.3, 11), (2, 1)).astype(np.float32)  # constant sensors, biases included
    y_rest[1, T.SENSOR_FRAME_LATERAL_ACCEL] = 0.0  # the filters start with the accelerometer at rest
    policy.reset(2)
    baseline.reset(2)
    for _ in range(5):
        np.testing.assert_array_equal(policy.act(y_rest)[1], baseline.act(y_rest)[1])
    for _ in range(1000):  # an accelerometer bias washes out (0.5 Hz)
        u, u_base = policy.act(y_rest), baseline.act(y_rest)
    np.testing.assert_allclose(u, u_base, atol=1e-6)
    moving = (y_rest + rng.normal(0, 0.3, (2, 11))).astype(np.float32)
    assert np.abs(policy.act(moving) - baseline.act(moving)).max() > 1e-2


def test_a_residual_student_linear_model_follows_act(bank_and_teacher):
    """The margins' model (the baseline's model beside the correction's Jacobian on stacked
    washed-out features) follows act; without the correction's path it does not."""
    from bogie_agents.design.margins import controller_model

    env_cfg = bank_and_teacher[0]
    policy, frames = _residual_student(env_cfg)
    y0 = np.zeros(11)
    y0[6] = 0.2  # the speed entry: about 300 km/h
    speed_kmh = float(frames.features.filters.speed_kmh(y0[None])[0])
    ctrl = policy.controller_model(11, speed_kmh, y0)
    u0 = policy.steady_action(y0)
    assert check_controller_model(policy, ctrl, y0, u0, steps=12) < 2e-2
    base_only = controller_model(frames.baseline, 11, speed_kmh, y0)
    assert check_controller_model(policy, base_only, y0, u0, steps=12) > 0.1


def test_residual_training_inputs_and_commands_are_the_saved_students(tmp_path, bank_and_teacher):
    """Rollouts driven by a residual student (beta 0) send what the saved and loaded student sends
    for the same observations, and its inputs are the student's; the fit targets are the
    correction that the teacher's command asks for on top of the baseline's."""
    from bogie_agents.controllers.distilled import ResidualFrames

    env_cfg, bank, _ = bank_and_teacher
    teacher = TeacherBank(env_cfg, bank)
    policy, _ = _residual_student(env_cfg)
    roll = Rollouts(env_cfg, 2, bank, teacher, 3, seed=5, residual=RESIDUAL)
    observations, sent, labels = [], [], []
    step, command = roll.task.step, teacher.command

    def record_step(actions):
        observations.append(roll.task.obs.copy())
        sent.append(np.array(actions))
        return step(actions)

    def record_label(obs):
        labels.append(command(obs))
        return labels[-1]

    roll.task.step, teacher.command = record_step, record_label
    steps = 30
    inputs, targets, _ = roll.run(steps, policy.network, beta=0.0)
    assert not roll.task.done.any()
    save_student(tmp_path / "s", policy.network, 3, 11, 4, {"env_id": "Bogie/Hunting-v1", "residual": {**RESIDUAL, "env_config": env_cfg}})
    student = load_policy(str(tmp_path / "s"), env_cfg)  # plain arrays: no trust needed
    student.reset(2)
    fresh = ResidualFrames(3, env_cfg, RESIDUAL["baseline"], RESIDUAL["scale"], 4)
    fresh.reset(2)
    inputs, targets = inputs.reshape(steps, 2, -1), targets.reshape(steps, 2, -1)
    for t in range(steps):
        np.testing.assert_array_equal(student.act(observations[t]), sent[t])
        x, base = fresh.inputs(observations[t])
        np.testing.assert_array_equal(x, inputs[t])
        np.testing.assert_allclose(targets[t], np.clip((labels[t] - base) / RESIDUAL["scale"], -1, 1), atol=1e-6)
    assert np.abs(np.diff(np.array(sent), axis=0)).max() > 1e-2
    assert np.abs(targets).max() > 1e-2


def test_residual_configs_and_files_are_checked(tmp_path, bank_and_teacher):
    with pytest.raises(ConfigError, match="student.residual.baseline"):
        load_config(None, {"student": {"residual": {"baseline": "nope"}}})
    with pytest.raises(ConfigError, match="student.residual.scale"):
        load_config(None, {"student": {"residual": {"baseline": "robust_steering", "scale": 0}}})
    with pytest.raises(ConfigError, match="'student.mirror' = false"):
        load_config(None, {"student": {"residual": {"baseline": "robust_steering"}, "mirror": False}})
    assert load_config(None, {"student": {"residual": {"baseline": "lqg"}}})["student"]["residual"] == {"baseline": "lqg", "scale": 1.0}
    with pytest.raises(ConfigError, match="'fit.loop_penalty' is not allowed with 'student.mirror' = false"):
        load_config(None, {"student": {"mirror": False}, "fit": {"loop_penalty": {}}})
    assert load_config(None, {"fit": {"loop_penalty": {}}})["fit"]["loop_penalty"]["gain"] == 2.0  # a plain mirrored student
    for bad, match in (({"gain": 0.5}, "loop_penalty.gain"), ({"points": [[300.0]]}, "loop_penalty.points"), ({"wieght": 1}, "keys")):
        with pytest.raises(ConfigError, match=match):
            load_config(None, {"student": {"residual": {"baseline": "lqg"}}, "fit": {"loop_penalty": bad}})
    policy, _ = _residual_student(bank_and_teacher[0])
    save_student(tmp_path, policy.network, 3, 11, 4, {"residual": {"baseline": "robust_steering", "scale": 2.0, "env_config": bank_and_teacher[0]}})
    with pytest.raises(ConfigError, match=r"'residual'.scale = 2.0"):
        load_student(tmp_path)


def test_the_loop_penalty_is_the_margins_closed_loop(bank_and_teacher):
    """The penalty's affine loop ``A0 + B (scale J) Phi`` of a random residual student equals the
    closed-loop matrix that ``bogie margins`` builds from the student's own linear model, in each
    variant (a loop gain, more delay); its growth bound is above the true growth rate and close
    to it."""
    import torch

    from bogie_agents.design.margins import linear_loop, plant_bogie
    from bogie_agents.training.loop_penalty import LoopPenalty, check_penalty_config

    env_cfg = bank_and_teacher[0]
    policy, frames = _residual_student(env_cfg, weight=0.6)
    settings = check_penalty_config({"points": [[350.0, 0.1]], "stable_points": [], "gain": 2.0, "extra_delay_steps": 1, "horizon_log2": 12})
    penalty = LoopPenalty(frames, env_cfg, settings)
    nominal, delayed = penalty.terms
    assert len(nominal.variants) == 5 and len(delayed.variants) == 1
    loop = linear_loop(policy, env_cfg, 350.0, plant_bogie(env_cfg, 0.1))
    bounds = penalty.growth_bounds_of(policy.network)
    net = policy.network
    linears = [type("L", (), {"weight": torch.from_numpy(w.astype(np.float64)), "bias": torch.from_numpy(b.astype(np.float64))})
               for w, b in zip(net.weights, net.biases)]  # fmt: skip
    j = frames.scale * penalty.jacobian(linears, torch.from_numpy(net.mean), torch.from_numpy(net.std), torch.from_numpy(nominal.x0)).numpy()
    for terms, lp in ((nominal, loop), (delayed, loop.with_extra_delay(1))):
        for v, gains in enumerate([np.ones(4)] + [np.where(np.arange(4) == k, 2.0, 1.0) for k in range(4)]):
            if v >= len(terms.variants):
                break
            t = terms.similarity
            a = (terms.a0[v] + terms.b[v] @ j @ terms.phi) * t[:, None] / t[None, :]  # undo the balancing
            np.testing.assert_allclose(a, lp.closed_loop_matrix(gains), rtol=1e-9, atol=1e-9 * np.abs(lp.closed_loop_matrix(gains)).max())
    true_growth = [loop.growth_rate(g) for g in [np.ones(4)] + [np.where(np.arange(4) == k, 2.0, 1.0) for k in range(4)]]
    true_growth.append(loop.with_extra_delay(1).growth_rate())
    assert np.all(bounds >= np.array(true_growth) - 1e-9)
    assert np.all(bounds <= np.array(true_growth) + 0.5)  # balanced, 41 s horizon: the transient's share is small


def test_the_loop_penalty_of_a_plain_student_is_the_margins_closed_loop(bank_and_teacher):
    """For a plain mirrored student (frames of observation and last command) the penalty's affine
    loop equals the closed loop ``bogie margins`` builds from the student's own linear model
    (:func:`student_controller_model`, its operating command found by root), nominal and with a
    loop gain; its exact growth rates are the margins' loops'. Without mirror signs it is refused."""
    import torch

    from bogie_agents.design.margins import linear_loop, plant_bogie
    from bogie_agents.training.distill import mirror_signs
    from bogie_agents.training.loop_penalty import LoopPenalty, check_penalty_config

    env_cfg = bank_and_teacher[0]
    task = HuntingTask(1, env_cfg)
    history, n_y, n_u = 3, task.observation_dim, task.action_dim
    mirror = mirror_signs(task, history)
    rng = np.random.default_rng(11)
    n_in = history * (n_y + n_u)
    network = StudentNetwork([rng.normal(0, 0.3, (16, n_in)), rng.normal(0, 0.3, (n_u, 16))], [rng.normal(0, 0.1, 16), rng.normal(0, 0.1, n_u)],
                             np.where(mirror < 0, 0.0, 0.2), np.where(mirror < 0, 0.8, 0.5), mirror)  # fmt: skip
    policy = DistilledPolicy(network, history, n_y, n_u)
    settings = check_penalty_config({"points": [[350.0, 0.1]], "stable_points": [], "gain": 2.0, "extra_delay_steps": 1, "horizon_log2": 12})
    penalty = LoopPenalty(policy.frames, env_cfg, settings, mirror=mirror)
    nominal, delayed = penalty.terms
    loop = linear_loop(policy, env_cfg, 350.0, plant_bogie(env_cfg, 0.1))
    np.testing.assert_allclose(loop.u_eq, 0.0, atol=1e-12)  # odd: no command at rest
    linears = [type("L", (), {"weight": torch.from_numpy(w.astype(np.float64)), "bias": torch.from_numpy(b.astype(np.float64))})
               for w, b in zip(network.weights, network.biases)]  # fmt: skip
    j = penalty.jacobian(linears, torch.from_numpy(network.mean), torch.from_numpy(network.std), torch.from_numpy(nominal.x0)).numpy()
    variants = [np.ones(n_u)] + [np.where(np.arange(n_u) == k, 2.0, 1.0) for k in range(n_u)]
    for terms, lp in ((nominal, loop), (delayed, loop.with_extra_delay(1))):
        for v, gains in enumerate(variants[: len(terms.variants)]):
            t = terms.similarity
            a = (terms.a0[v] + terms.b[v] @ j @ terms.phi) * t[:, None] / t[None, :]
            expected = lp.closed_loop_matrix(gains)  # the margins hold the frames in float32: 1e-6
            np.testing.assert_allclose(a, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())
    true_growth = [loop.growth_rate(g) for g in variants] + [loop.with_extra_delay(1).growth_rate()]
    np.testing.assert_allclose(penalty.growth_rates_of(network), true_growth, rtol=1e-6, atol=1e-6)
    assert np.all(penalty.growth_bounds_of(network) >= np.array(true_growth) - 1e-9)
    with pytest.raises(ValueError, match="mirror signs"):
        LoopPenalty(policy.frames, env_cfg, settings)


def test_the_fault_points_are_the_margins_loops_with_half_the_creep_and_a_failed_channel(bank_and_teacher):
    """At a fault point the penalty's loops are the margins' closed loop with each channel's
    command cut and, on the scenario plant with creep_factor 0.5 (the protocol's creep -50 %), the
    nominal command; the creep loop differs from the nominal one (the plant did change)."""
    import torch

    from bogie_agents.design.margins import linear_loop, plant_bogie
    from bogie_agents.training.loop_penalty import LoopPenalty, check_penalty_config
    from bogie_env.envs.config import bogie_params
    from bogie_env.envs.scenario import Scenario, scenario_model

    env_cfg = bank_and_teacher[0]
    policy, frames = _residual_student(env_cfg, weight=0.6)
    settings = check_penalty_config({"points": [[300.0, 0.025]], "stable_points": [], "fault_points": [[330.0, 0.025]]})
    penalty = LoopPenalty(frames, env_cfg, settings)
    failed, creep = penalty.terms[-2:]
    assert failed.variants == ("frame_lateral failed", "frame_yaw failed", "wheelset1_yaw failed", "wheelset2_yaw failed") and creep.variants == ("creep -50%",)
    nominal_model = plant_bogie(env_cfg, 0.025)
    creep_model = scenario_model(bogie_params(env_cfg), Scenario(conicity=0.025, creep_factor=0.5), nominal_model)
    net = policy.network
    linears = [type("L", (), {"weight": torch.from_numpy(w.astype(np.float64)), "bias": torch.from_numpy(b.astype(np.float64))})
               for w, b in zip(net.weights, net.biases)]  # fmt: skip
    j = frames.scale * penalty.jacobian(linears, torch.from_numpy(net.mean), torch.from_numpy(net.std), torch.from_numpy(failed.x0)).numpy()
    cases = [(failed, v, linear_loop(policy, env_cfg, 330.0, nominal_model), np.where(np.arange(4) == v, 0.0, 1.0)) for v in range(4)]
    cases.append((creep, 0, linear_loop(policy, env_cfg, 330.0, creep_model), np.ones(4)))
    for terms, v, lp, gains in cases:
        t = terms.similarity
        a = (terms.a0[v] + terms.b[v] @ j @ terms.phi) * t[:, None] / t[None, :]
        expected = lp.closed_loop_matrix(gains)
        np.testing.assert_allclose(a, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    assert not np.allclose(cases[-1][2].closed_loop_matrix(), cases[0][2].closed_loop_matrix())
    true_growth = np.array([lp.growth_rate(g) for _, _, lp, g in cases])
    bounds = penalty.growth_bounds_of(net)[-5:]
    assert np.all(bounds >= true_growth - 1e-9)
    # the exact rates (of the balanced matrices) are the margins' loops' growth, named by kind
    np.testing.assert_allclose(penalty.growth_rates_of(net)[-5:], true_growth, rtol=1e-6, atol=1e-6)
    assert [r[2:] for r in penalty.named_rows()[-5:]] == [("faults", v) for v in failed.variants + creep.variants]
    assert {r[2] for r in penalty.named_rows()[:-5]} == {"margins"}


def test_fault_degraded_adds_the_protocols_degraded_plants_by_name(bank_and_teacher):
    """``fault_degraded`` puts each named degraded bogie of the protocol on its own plant at every
    fault point: the Kpx -50 % loop is the margins' loop on that scenario's plant; unknown names are refused."""
    import torch

    from bogie_agents.design.margins import linear_loop, plant_bogie
    from bogie_agents.evaluation.stability_protocol import DEGRADED
    from bogie_agents.training.loop_penalty import LoopPenalty, check_penalty_config
    from bogie_env.envs.config import bogie_params
    from bogie_env.envs.scenario import Scenario, scenario_model

    env_cfg = bank_and_teacher[0]
    policy, frames = _residual_student(env_cfg, weight=0.6)
    settings = check_penalty_config({"points": [[300.0, 0.025]], "stable_points": [], "fault_points": [[330.0, 0.025]],
                                     "fault_degraded": ["Kpx-50%", "creep-50%"]})  # fmt: skip
    penalty = LoopPenalty(frames, env_cfg, settings)
    kpx, creep = penalty.terms[-2:]
    assert kpx.variants == ("Kpx -50%",) and creep.variants == ("creep -50%",)
    model = scenario_model(bogie_params(env_cfg), Scenario(conicity=0.025, **DEGRADED["Kpx-50%"]), plant_bogie(env_cfg, 0.025))
    lp = linear_loop(policy, env_cfg, 330.0, model)
    net = policy.network
    linears = [type("L", (), {"weight": torch.from_numpy(w.astype(np.float64)), "bias": torch.from_numpy(b.astype(np.float64))})
               for w, b in zip(net.weights, net.biases)]  # fmt: skip
    j = frames.scale * penalty.jacobian(linears, torch.from_numpy(net.mean), torch.from_numpy(net.std), torch.from_numpy(kpx.x0)).numpy()
    t = kpx.similarity
    a = (kpx.a0[0] + kpx.b[0] @ j @ kpx.phi) * t[:, None] / t[None, :]
    np.testing.assert_allclose(a, lp.closed_loop_matrix(), rtol=1e-9, atol=1e-9 * np.abs(a).max())
    assert not np.allclose(kpx.a0[0], creep.a0[0])
    assert not np.allclose(lp.closed_loop_matrix(), linear_loop(policy, env_cfg, 330.0, plant_bogie(env_cfg, 0.025)).closed_loop_matrix())
    for bad in (["Kpx"], ["creep-50%", "creep-50%"], "creep-50%"):
        with pytest.raises(ConfigError, match="fault_degraded"):
            check_penalty_config({"fault_degraded": bad})


def _select_module():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "studies" / "distill_select.py"
    spec = importlib.util.spec_from_file_location("distill_select", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_loop_bound_selection_takes_the_last_certified_iteration(tmp_path):
    """``--rule loop-bound``: the last iteration whose worst bound is within the limit, not the lowest bound."""
    bounds = [2.7, -0.5, 0.1, -0.1, -0.3, 0.2]
    (tmp_path / "progress.json").write_text(json.dumps({"iterations": [{"iteration": k, "growth_bound_max_per_s": b}
                                                                       for k, b in enumerate(bounds)]}))  # fmt: skip
    (tmp_path / "student.json").write_text(json.dumps({"config": {"fit": {"loop_penalty": {}}}}))
    for k in range(1, len(bounds) + 1):
        (tmp_path / "iterations" / f"{k:03d}").mkdir(parents=True)
        (tmp_path / "iterations" / f"{k:03d}" / "tag").write_text(str(k))
    select = _select_module()
    assert select.main(["--run", str(tmp_path), "--rule", "loop-bound"]) == 0
    assert (tmp_path / "selected" / "tag").read_text() == "5"
    assert json.loads((tmp_path / "selection.json").read_text())["chosen"] == 5
    # a looser limit admits the last iteration; a run without the penalty is refused by name
    (tmp_path / "student.json").write_text(json.dumps({"config": {"fit": {"loop_penalty": {"max_growth_per_s": 0.5}}}}))
    select.main(["--run", str(tmp_path), "--rule", "loop-bound"])
    assert (tmp_path / "selected" / "tag").read_text() == "6"
    (tmp_path / "student.json").write_text(json.dumps({"config": {"fit": {"loop_penalty": None}}}))
    with pytest.raises(SystemExit, match="without fit.loop_penalty"):
        select.main(["--run", str(tmp_path), "--rule", "loop-bound"])


def test_margins_selection_takes_the_last_iteration_that_meets_the_floors(tmp_path):
    """``--rule margins``: checked from the last iteration back, the first that passes is chosen and
    the earlier ones are not checked; none passing selects nothing and says so."""
    for k in range(1, 7):
        (tmp_path / "iterations" / f"{k:03d}").mkdir(parents=True)
        (tmp_path / "iterations" / f"{k:03d}" / "tag").write_text(str(k))
    select = _select_module()
    checked = []

    def figures(folder):
        checked.append(int(folder.name))
        point = {"conicity": 0.1, "unstable_at_kmh": [], "gain_margin": 2.5, "delay_margin_s": 0.02, "all_loops_delay_margin_s": None}
        return {"points": [point], "fault_growth_max_per_s": -0.4, "passes": int(folder.name) in (3, 4)}

    assert select.select_by_margins(tmp_path, 2, figures) == 0
    assert checked == [6, 5, 4] and (tmp_path / "selected" / "tag").read_text() == "4"
    assert json.loads((tmp_path / "selection.json").read_text())["chosen"] == 4
    with pytest.raises(SystemExit, match="meets the margin floors"):
        select.select_by_margins(tmp_path, 5, figures)
    assert json.loads((tmp_path / "selection.json").read_text())["chosen"] is None


def test_residual_scale_study_rescales_only_the_authority(tmp_path, bank_and_teacher):
    """studies/residual_scale.py: the copy acts as the original with the correction scaled (the
    baseline's part unchanged), and bad scales or non-residual students are refused by name."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "studies" / "residual_scale.py"
    spec = importlib.util.spec_from_file_location("residual_scale", path)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    env_cfg = bank_and_teacher[0]
    policy, _ = _residual_student(env_cfg)
    save_student(tmp_path / "s", policy.network, 3, 11, 4, {"residual": {**RESIDUAL, "env_config": env_cfg}})
    study.scaled_copy(tmp_path / "s", 0.25, tmp_path / "q")
    assert load_student(tmp_path / "q").meta["residual"]["scale"] == 0.25
    from bogie_agents.controllers.distilled import ResidualFrames
    from bogie_agents.controllers.residual import compose

    obs = np.random.default_rng(1).uniform(-0.3, 0.3, (2, 11))
    obs[:, 6] = [0.1, 0.25]  # the speed entries: two speeds inside the schedule below
    copy = load_student(tmp_path / "q")
    copy.reset(2)
    frames = ResidualFrames(3, env_cfg, RESIDUAL["baseline"], 0.25, 4)
    frames.reset(2)
    x, base = frames.inputs(obs)
    np.testing.assert_allclose(copy.act(obs), compose(base, policy.network.forward(x), 0.25), atol=1e-6)
    # a schedule over speed: each row gets the authority at its own speed
    from bogie_env.envs.task import speed_kmh_from_observation

    study.scaled_copy(tmp_path / "s", study.parse_scale("1@100,0.2@500"), tmp_path / "v")
    sched = load_student(tmp_path / "v")
    sched.reset(2)
    speeds = speed_kmh_from_observation(obs, env_cfg["observation"]["type"])
    expected = np.interp(speeds, [100.0, 500.0], [1.0, 0.2])[:, None]
    assert 100 < speeds.min() and speeds.max() < 500 and abs(expected[0, 0] - expected[1, 0]) > 1e-3
    np.testing.assert_allclose(sched.act(obs), compose(base, policy.network.forward(x), expected), atol=1e-6)
    for bad in ("1.5", "1@300,0.5@200", "0@100,1@200", "x"):
        with pytest.raises(ConfigError, match="--scale"):
            study.parse_scale(bad)
    with pytest.raises(ConfigError, match="--scale = 1.5"):
        study.scaled_copy(tmp_path / "s", 1.5, tmp_path / "r")
    save_student(tmp_path / "plain", policy.network, 3, 11, 4, {})
    with pytest.raises(ConfigError, match="'residual' is missing"):
        study.scaled_copy(tmp_path / "plain", 0.5, tmp_path / "r")
