"""A low-frequency curving assist for ``Bogie/Hunting-v1``, complementary to washed-out damping.

:class:`CurvingAssist` maps the v1 observation to a steady steering command that moves the
wheelsets towards the radial position in a curve (active steering: Perez, Goodall, Mei & Fu's
reviews of active wheelset steering; Bombardier's actively steered bogies). It is zero on
straight track and for sensor biases (a deadband on the curvature estimate), so it leaves
straight-track stability to the damping controller it is added to.

Curvature estimate: the v1 sensors measure each wheelset's yaw relative to the frame as
``r_i = psi_i - psi_b`` with both angles from the *local* track tangent (``bogie_env.envs.task``),
while the primary yaw springs are deflected by ``d_i = psi_i + Theta_i - psi_b`` with
``Theta_i = s_i L1 kappa`` in a circular curve (docs/model.md, C6/C8). So
``r_1 - r_2 = (d_1 - d_2) - 2 L1 kappa``, and the springs' differential deflection is the
wheelset torques' difference over the yaw stiffness, ``d_1 - d_2 = (T_1 - T_2 + dM)/k_psi``
(dM: the creep moments' difference, small on a yaw-stiff bogie). The estimate removes the
torques' share, so it does not fall as the assist steers the wheelsets:

    kappa_hat = -LP(r_1 - r_2 - (T_1 - T_2) / k_psi) / (2 L1)

with LP a cascade of ``lowpass_order`` first-order low-passes at ``lowpass_hz`` and
``T_1 - T_2`` the wheelset torques as observed (the v1 observation's actuator forces, the
damping's included), or the assist's own previous torques when the forces are not observed
(then the damping's torques and a failed or stuck wheelset actuator are not seen: the estimate
is off by their share).
NB: a real displacement transducer measures ``d_i``,
which does not carry kappa; on a real vehicle the estimate would be the absolute yaw rate over
the speed (a gyro). The v1 gyro measures the frame's yaw rate in track axes (zero in a steady
curve), so in the env the curvature reaches the controller only through ``r_i``. See
docs/controllers.md.

Commands (torques, N m, + for a curve to the left):

- wheelset i: ``s_i k_psi L1 kappa_eff`` (``s_1 = +1`` leading, ``s_2 = -1``), the moment
  that cancels the primary yaw springs' restoring moment at the radial position
  (``k_psi = 2 Kpx b1^2``; docs/model.md C8: with radial wheelsets and ``psi_b = 0`` the springs
  are deflected by ``+-L1 kappa``), times ``wheelset_gain``;
- frame yaw (optional, ``frame_gain``): ``frame_gain k_psi L1 kappa_eff``;

each limited to ``fraction`` of the channel's force limit, so the damping controller keeps
the rest. Only channels in ``force`` mode are commanded: a ``semi_active`` channel's action sets
a damper's coefficient, not a torque, so the assist leaves it at zero.
``kappa_eff = sign(kappa_hat) max(|kappa_hat| - deadband, 0)``.
"""

from __future__ import annotations

import math

import numpy as np

from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.envs import task as T
from bogie_env.envs.config import bogie_params
from bogie_env.params import ConfigError

from .lqr import Controller


class CurvingAssist(Controller):
    """The steady steering command (normalised, per active channel) from a low-passed curvature
    estimate with a deadband. ``command(obs)`` advances the filter; ``act`` is the command alone."""

    name = "curving_assist"
    observation_type = "sensors"

    def __init__(self, env_config: dict, lowpass_hz: float = 0.3, lowpass_order: int = 2, deadband_1pm: float = 5e-5,
                 wheelset_gain: float = 1.0, frame_gain: float = 0.0, fraction: float = 0.8) -> None:  # fmt: skip
        super().__init__(env_config)
        if env_config["observation"]["type"] != "sensors":
            raise ConfigError(f"curving_assist needs observation.type = 'sensors'; got {env_config['observation']['type']!r}")
        checks = {"lowpass_hz": (lowpass_hz, lowpass_hz > 0), "lowpass_order": (lowpass_order, lowpass_order in (1, 2, 3)),
                  "deadband_1pm": (deadband_1pm, deadband_1pm >= 0), "fraction": (fraction, 0 <= fraction <= 1),
                  "wheelset_gain": (wheelset_gain, math.isfinite(wheelset_gain)), "frame_gain": (frame_gain, math.isfinite(frame_gain))}  # fmt: skip
        for field, (value, ok) in checks.items():
            if not ok:
                raise ConfigError(f"curving_assist: {field} = {value!r} is not allowed (lowpass_hz > 0, lowpass_order 1-3, "
                                  "deadband_1pm >= 0, 0 <= fraction <= 1, finite gains)")  # fmt: skip
        p = bogie_params(env_config)
        self.semi_wheelbase = p.L1
        self.yaw_stiffness = 2.0 * p.Kpx * p.b1**2  # N m/rad, primary yaw stiffness of one wheelset
        self.alpha = math.exp(-2 * math.pi * lowpass_hz * self.dt)
        self.order = int(lowpass_order)
        self.deadband = float(deadband_1pm)
        self.fraction = float(fraction)
        gain_by_channel = {"wheelset1_yaw": wheelset_gain, "wheelset2_yaw": -wheelset_gain, "frame_yaw": frame_gain}
        # only force channels take a torque command: a semi-active channel's action sets a damper's
        # coefficient (docs/environment.md), which a steady steering offset would only unbalance
        force_mode = [env_config["actuators"][CHANNEL_NAMES[k]]["mode"] == "force" for k in self.active]
        #: normalised command per 1/m of effective curvature, per active channel (0: not commanded)
        self.gain = np.array([gain_by_channel.get(CHANNEL_NAMES[k], 0.0) * self.yaw_stiffness * self.semi_wheelbase * force
                              for k, force in zip(self.active, force_mode)]) / self.max_force  # fmt: skip
        # the commanded torque columns of the two wheelsets (None: not commanded, no torque), for
        # the estimate when the forces are not observed
        self.command_columns = tuple(next((j for j, k in enumerate(self.active) if CHANNEL_NAMES[k] == name and self.gain[j] != 0.0), None)
                                     for name in ("wheelset1_yaw", "wheelset2_yaw"))  # fmt: skip
        # the observed actuator forces (normalised by each active channel's limit), when observed
        first = len(T.SENSORS) + 1
        columns = {CHANNEL_NAMES[k]: (first + j, self.max_force[j]) for j, k in enumerate(self.active)}
        self.force_columns, self.force_scale = None, 0.0
        if env_config["observation"]["include_actuators"] and "wheelset1_yaw" in columns and "wheelset2_yaw" in columns:
            (c1, s1), (c2, s2) = columns["wheelset1_yaw"], columns["wheelset2_yaw"]
            if s1 != s2:
                raise ConfigError(f"curving_assist: the wheelset yaw channels' max_force differ ({s1} vs {s2} N m)")
            self.force_columns, self.force_scale = (c1, c2), float(s1)
        self.lp = np.zeros((0, self.order))
        self.torque = np.zeros(0)  # (n,) T_1 - T_2 commanded by the assist at the last step, N m

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        if rows is None or self.lp.shape[0] != n_envs:
            self.lp = np.zeros((n_envs, self.order))
            self.torque = np.zeros(n_envs)
        else:
            self.lp[rows] = 0.0
            self.torque[rows] = 0.0

    def raw_curvature(self, obs: np.ndarray) -> np.ndarray:
        """(n,) the unfiltered curvature estimate, 1/m (+ left), without the assist's own
        deflection of the primary yaw springs (module docstring)."""
        r = (obs[:, T.SENSOR_WHEELSET1_YAW] - obs[:, T.SENSOR_WHEELSET2_YAW]).astype(float) * T.REL_YAW_SCALE
        if self.force_columns is not None:  # the measured wheelset torques (the damping's too)
            difference = (obs[:, self.force_columns[0]] - obs[:, self.force_columns[1]]).astype(float) * self.force_scale
        else:  # the assist's own commanded torques (a channel off or not commanded adds none)
            difference = self.torque
        return -(r - difference / self.yaw_stiffness) / (2.0 * self.semi_wheelbase)

    def curvature(self, obs: np.ndarray) -> np.ndarray:
        """Advance the low-pass on one observation per row; the filtered estimate (n,), 1/m.
        The filter starts from zero curvature: a row's first observation after ``reset`` holds
        the initial perturbation (wheelset yaws of a few tenths of a mrad, oscillating), which
        settled on would read as a curve; a start inside a curve ramps the assist up instead."""
        obs = np.asarray(obs)
        if self.lp.shape[0] != obs.shape[0]:
            self.reset(obs.shape[0])
        x = self.raw_curvature(obs)
        for j in range(self.order):
            self.lp[:, j] = self.alpha * self.lp[:, j] + (1 - self.alpha) * x
            x = self.lp[:, j]
        return x.copy()

    @property
    def curvature_estimate(self) -> np.ndarray:
        """(n,) the last filtered curvature estimate, 1/m (+ left)."""
        return self.lp[:, -1].copy()

    def command(self, obs: np.ndarray) -> np.ndarray:
        """(n, n_active) the assist's normalised command, each entry within ``fraction``."""
        k = self.curvature(obs)
        k_eff = np.sign(k) * np.maximum(np.abs(k) - self.deadband, 0.0)
        u = np.clip(k_eff[:, None] * self.gain[None, :], -self.fraction, self.fraction)
        self.torque = np.zeros(k.shape)
        for sign, j in zip((1.0, -1.0), self.command_columns):
            if j is not None:
                self.torque = self.torque + sign * u[:, j] * self.max_force[j]
        return u

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.command(obs).astype(np.float32)


class SteeringController(Controller):
    """A damping controller plus :class:`CurvingAssist`: ``clip(u_damping + u_assist, -1, 1)``."""

    name = "robust_steering"
    observation_type = "sensors"

    def __init__(self, env_config: dict, base: Controller | None = None, **assist) -> None:
        super().__init__(env_config)
        from .robust import RobustDampingController

        self.base = base if base is not None else RobustDampingController(env_config)
        self.assist = CurvingAssist(env_config, **assist)

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        self.base.reset(n_envs, rows)
        self.assist.reset(n_envs, rows)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.clip(self.base.act(obs) + self.assist.command(obs), -1.0, 1.0).astype(np.float32)

    def controller_model(self, n_obs: int, speed_kmh: float, y0: np.ndarray):
        """The small-signal model about straight track: the base's (inside the deadband the
        assist's command and its derivative are zero)."""
        return self.base.controller_model(n_obs, speed_kmh, y0)
