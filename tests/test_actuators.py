"""The actuator-channel table and the maps derived from it (bogie_env/actuators.py).

Oracles: virtual work (a channel's force times its relative velocity is the power its
generalised forces deliver), the compiled helpers against the matrices, and the damping
Jacobian against a finite difference of the right-hand side with the dampers in the loop."""

import numpy as np
import pytest
from numba import njit

from bogie_env import actuators as A
from bogie_env.dynamics import INPUT_NAMES, N_INPUTS, N_STATES, state_index

#: The worked example of docs/extending.md: a yaw damper/actuator between the two wheelsets.
INTER_WHEELSET_YAW = A.Channel(
    "interwheelset_yaw", "wheelset1_yaw_torque", "wheelset2_yaw_torque", "dpsi1", "dpsi2", "N m",
    {"mode": "off", "max_force": 10e3, "c_min": 0.0, "c_max": 5.0e5, "bandwidth_hz": 10.0, "delay_steps": 0},
)


def input_velocity_matrix(model):
    """(N_INPUTS, N_STATES): the velocity each generalised input does work on. Read from the
    dynamics' input matrix: input j accelerates the DOF whose velocity state is row j's target."""
    b = model.input_matrix()
    m = np.zeros((N_INPUTS, N_STATES))
    for j in range(N_INPUTS):
        (rows,) = np.nonzero(b[:, j])
        assert rows.size == 1
        m[j, rows[0]] = 1.0
    return m


@pytest.mark.parametrize("channels", [A.CHANNELS, A.CHANNELS + (INTER_WHEELSET_YAW,)], ids=["shipped", "with-example"])
def test_virtual_work_links_the_velocity_and_force_maps(paper_model, channels):
    """Q . qdot == u . v for every state and channel force: G^T W = V."""
    g = A.force_matrix(channels=channels)
    v = A.velocity_matrix(channels=channels)
    w = input_velocity_matrix(paper_model)
    assert np.array_equal(g.T @ w, v)
    rng = np.random.default_rng(0)
    x, u = rng.normal(size=N_STATES), rng.normal(size=len(channels))
    assert (g @ u) @ (w @ x) == pytest.approx(u @ (v @ x), rel=1e-12)


def test_table_matches_the_dynamics_names():
    for c in A.CHANNELS:
        assert c.input in INPUT_NAMES and (c.reaction is None or c.reaction in INPUT_NAMES)
        state_index(c.velocity)
        assert c.relative_to is None or state_index(c.relative_to) >= 0
    assert A.CHANNEL_NAMES == ("frame_lateral", "frame_yaw", "wheelset1_yaw", "wheelset2_yaw")


@njit
def _compiled_maps(x, u, v_out, q_out):
    for k in range(A.N_CHANNELS):
        v_out[k] = A.channel_velocity(x, k)
    A.generalised_forces(u, q_out)


def test_compiled_helpers_equal_the_matrices():
    rng = np.random.default_rng(1)
    x, u = rng.normal(size=N_STATES), rng.normal(size=A.N_CHANNELS)
    v, q = np.empty(A.N_CHANNELS), np.empty(N_INPUTS)
    _compiled_maps(x, u, v, q)
    assert np.allclose(v, A.velocity_matrix() @ x, rtol=0, atol=1e-15)
    assert np.allclose(q, A.force_matrix() @ u, rtol=0, atol=1e-15)


def test_damping_jacobian_is_the_derivative_of_the_damper_forces(paper_model):
    """-B G diag(c) V against a central difference of rhs(x, Q = -G diag(c) V x)."""
    c = np.linspace(2e4, 5e5, A.N_CHANNELS)
    speed = 90.0
    x0 = paper_model.equilibrium(speed)

    def f(x):
        return paper_model.rhs(x, speed, inputs=A.force_matrix() @ (-c * (A.velocity_matrix() @ x)))

    jac_with = np.empty((N_STATES, N_STATES))
    for i in range(N_STATES):
        h = 1e-7
        e = np.zeros(N_STATES)
        e[i] = h
        jac_with[:, i] = (f(x0 + e) - f(x0 - e)) / (2 * h)
    added = jac_with - paper_model.jacobian(x0, speed)
    expected = A.damping_jacobian(paper_model.input_matrix(), c)
    assert np.allclose(added, expected, atol=1e-4 * np.max(np.abs(expected)))
    assert np.max(np.abs(expected)) > 1.0  # not vacuous


def test_channel_table_modes_and_action_columns():
    settings = {name: dict(c.defaults) for name, c in zip(A.CHANNEL_NAMES, A.CHANNELS)}
    settings["frame_yaw"]["mode"] = "off"
    settings["wheelset1_yaw"]["mode"] = "semi_active"
    table = A.channel_table(settings)
    active = [k for k, name in enumerate(A.CHANNEL_NAMES) if settings[name]["mode"] != "off"]
    assert active[:3] == [0, 2, 3] and A.active_channels(settings) == active
    assert list(table[active, A.CH_ACTION]) == list(range(len(active)))
    assert np.all(np.delete(table[:, A.CH_ACTION], active) == -1)
    assert table[1, A.CH_MODE] == A.MODE_OFF and table[2, A.CH_MODE] == A.MODE_SEMI
    assert table[0, A.CH_DECAY_RATE] == pytest.approx(2 * np.pi * 10.0)


@njit
def _command_and_delay(table, actions, commands_out, targets_out):
    delay = np.zeros((A.DELAY_SLOTS, 2, A.N_CHANNELS))
    for step in range(actions.shape[0]):
        command = commands_out[step]  # a view: no array-slice assignment, whose compilation alone takes ~5 s
        for k in range(A.N_CHANNELS):
            A.command_from_action(table, k, actions[step], command)
        A.delayed_targets(delay, step, command, table, targets_out[step])


def test_commands_and_delays():
    """Force: a * max_force; semi-active: c_min + (a + 1)/2 (c_max - c_min); a d-step delay
    hands over the command of d steps ago, and zero before the first one."""
    settings = {name: dict(c.defaults) for name, c in zip(A.CHANNEL_NAMES, A.CHANNELS)}
    settings["frame_yaw"].update(mode="semi_active", c_min=1e3, delay_steps=2)
    settings["wheelset2_yaw"].update(delay_steps=A.MAX_DELAY_STEPS)
    table = A.channel_table(settings)
    rng = np.random.default_rng(2)
    actions = rng.uniform(-1, 1, (25, 4))
    commands = np.empty((25, 2, A.N_CHANNELS))
    targets = np.empty((25, 2, A.N_CHANNELS))
    _command_and_delay(table, actions, commands, targets)
    assert np.allclose(commands[:, A.FORCE, 0], actions[:, 0] * 10e3)
    assert np.all(commands[:, A.FORCE, 1] == 0.0)
    assert np.allclose(commands[:, A.DAMPING, 1], 1e3 + 0.5 * (actions[:, 1] + 1) * (5e5 - 1e3))
    assert np.array_equal(targets[:, :, 0], commands[:, :, 0])  # no delay
    assert np.all(targets[:2, :, 1] == 0) and np.array_equal(targets[2:, :, 1], commands[:-2, :, 1])
    d = A.MAX_DELAY_STEPS
    assert np.all(targets[:d, :, 3] == 0) and np.array_equal(targets[d:, :, 3], commands[:-d, :, 3])
