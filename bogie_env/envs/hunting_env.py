"""``BogieHuntingEnv``: one bogie, speed ramping up, actuators against hunting."""

from __future__ import annotations

from typing import Any, Mapping

import gymnasium as gym
import numpy as np

from .config import make_config
from .task import HuntingTask


class BogieHuntingEnv(gym.Env):
    """
    ## Description

    A high-speed railway bogie runs on straight track while its speed ramps up, by default from
    300 to 600 km/h at 1 m/s². Above a critical speed a passive bogie starts *hunting*: a
    self-excited lateral and yaw oscillation of the wheelsets and frame that grows until the
    wheel flanges hit the rails. The agent drives actuators on the bogie to keep it stable to
    as high a speed as possible. The physics is the nonlinear 10-DOF bogie of Bustos et al.,
    "On the nonlinear hunting stability of a high-speed train bogie", *Nonlinear Dynamics*
    (2022) (`docs/model.md`), whose passive linear critical speed here is 358.6 km/h.

    ## Action Space

    `Box(-1, 1, (n,), float32)`, one entry per active actuator channel, in the order
    frame lateral, frame yaw, wheelset 1 yaw, wheelset 2 yaw (only the channels whose mode is
    not `"off"`). Out-of-range actions are clipped to [-1, 1]; NaN, inf or a wrong shape raise
    `ValueError`. Each channel (`config["actuators"][name]`) is either:

    - `"force"`: an actuator of force (N) or torque (N m) `a * max_force`;
    - `"semi_active"`: a damper whose coefficient is `c_min + (a + 1)/2 * (c_max - c_min)`; it
      only dissipates;
    - `"off"`.

    Every channel saturates at `max_force`, follows its command through a first-order lag of
    `bandwidth_hz`, and can delay it by `delay_steps` steps. Defaults: 10 kN frame lateral,
    15 kN m frame yaw, 15 kN m per wheelset (acting between the wheelset and the frame), 10 Hz,
    no delay. The `Bogie/HuntingPassive-v0` variant has no actuators; its action space is
    `Box(-1, 1, (1,))` and the action is ignored.

    ## Observation Space

    `Box(-10, 10, (m,), float32)`, clipped to its bounds. With `observation.type = "sensors"`
    (default), what an on-board system can measure:

    | index | observation | scale (value that reads 1) |
    |---|---|---|
    | 0 | frame lateral acceleration | 5 m/s² |
    | 1 | frame yaw rate | 0.1 rad/s |
    | 2, 3 | lateral displacement of wheelset 1, 2 relative to the frame (at the axle boxes) | flange clearance δ = 9 mm |
    | 4, 5 | yaw of wheelset 1, 2 relative to the frame | 5 mrad |
    | 6 | speed | (V − 450 km/h) / 150 km/h |
    | 7… | each active actuator's force / its `max_force` (if `include_actuators`) | 1 |

    With `observation.type = "state"`: the 20 states of the model (`bogie_env.STATE_NAMES`) scaled
    to O(1), then the speed and actuator forces as above. `observation.noise` (default 0) adds
    white Gaussian noise of that standard deviation *in observation units* to every entry, the
    actuator forces included: a generic robustness knob on top of everything else. It is not
    the sensor model of v1 (`sensors`, with physical noise densities and biases per channel and
    the one factor `sensors.noise_scale`; see "Bogie/Hunting-v1").

    ## Rewards

    Per step, `progress * (1 - penalty)`, where `progress` is the speed gained in the step in
    km/h (plus `time_weight * dt`, default 0) and
    `penalty = w_lat * mean_i min((y_rel,i/δ)², 1) + w_yaw * mean_i min((ψ_i − ψ_b)²/ψ_ref², 1)
    + w_effort * mean_k min((u_k/max_k)², 1)` with defaults 0.5, 0.2, 0.2 (their sum must stay
    below 1). So every step alive pays, and the return grows with the speed reached without
    hunting: a passive bogie that hunts at 360 km/h collects about 60 (x penalties) on the
    default ramp, one that reaches 600 km/h up to 300. `y_rel,i` is wheelset i's displacement
    relative to the rail; a blow-up step pays 0.

    ## Starting State

    The bogie starts at the equilibrium at the start speed with random lateral offsets of the
    wheelsets and frame (standard deviation `initial_perturbation`, 1 mm) and yaw angles
    (1 mm / 2 L1), at a random position along a periodic 262-km track-alignment profile. With
    probability `large_perturbation_probability` (default 0) the lateral offsets are instead
    large (uniform in [0.5, 1] x 12 mm, random signs): flange contact, as on a hunting cycle.

    ## Episode End

    - Termination: hunting is established: the exponentially weighted rms (over `window_m`,
      100 m of track) of either wheelset's displacement relative to the rail exceeds
      `rms_fraction * δ` (0.6 × 9 mm); or the numerics blow up (non-finite state, or a
      displacement beyond `blowup_m` = 0.1 m).
    - Truncation: the speed reaches the end speed, or the episode has run for the configured
      ramp's length plus 10 % (`env.unwrapped.max_episode_steps`; 100,000 steps at fixed speed).
      The registered ids add no other limit, so it follows the config;
      `gym.make(..., max_episode_steps=N)` adds a `TimeLimit` of N steps.

    ## Speed range

    A version supports the speeds of its ramp: v0 300-600 km/h, v1 100-600 km/h (the route
    variant: its routes' ranges, 160-350 km/h). The RK4 step is chosen for that range, and
    `reset(options=...)` speeds outside it are refused. `speed.supported_kmh: [low, high]`
    (within 30-850 km/h) widens it without moving the default ramp, e.g.
    `config={"speed": {"supported_kmh": [40, 600]}}` and then
    `reset(options={"start_kmh": 40, "end_kmh": 40, "accel": 0})`. The step is then chosen for the
    wider range, so it may take other substeps (`env.unwrapped.task.n_sub`) and give other
    trajectories than the registered id. Changing `speed.start_kmh` or `end_kmh` moves the
    default ramp and widens the range with it.

    ## Info

    `speed_kmh`, `hunting` (bool), `onset_speed_kmh` (None until hunting; NaN in the vector
    envs' arrays), `lateral_rms_m` (2,),
    `actuator_force` (4,) in N / N m and `actuator_power` (4,) in W (mechanical power delivered
    by each channel, mean over the step; negative = dissipated), `blowup` (bool).

    With config `info: {"criterion": true}` (off by default: they cost a front-end step
    measurably, `benchmarks/bench_env.py --criterion-info`), every info adds what a running-stability or safety
    criterion (EN 14363) is built from, at the end of the step, from the simulator's state and
    wheel-rail contact (`task.CRITERION_FIELDS`; `env.unwrapped.task.criterion_quantities()`
    gives them at any time, whatever the flag):

    | key | shape | meaning |
    |---|---|---|
    | `wheelset_lateral_rel_rail_m` | (2,) | each wheelset's lateral displacement relative to the rail, m, + left |
    | `flange_contact` | (2,) bool | wheelset in flange contact: abs(displacement relative to the rail) >= flange clearance (9 mm) |
    | `wheel_flange_contact` | (2, 2) bool | [wheelset, (left, right) wheel]: the left wheel at +clearance, the right at -clearance |
    | `sum_y_n` | (2,) | EN 14363's sum of guiding forces ΣY per wheelset, N: the rails' lateral force on the wheelset, + left |
    | `wheel_y_over_q` | (2, 2) | [wheelset, (left, right) wheel] Y/Q: the wheel's lateral force on its rail (+ outwards) over Q = axle load / 2 |
    | `y_over_q` | () | the largest of the four |

    Flange contact is the stability protocol's test and ΣY its function
    (`bogie_env.analysis.en14363.running_signals_rows`), so a criterion built on these fields
    reads what `bogie evaluate --parts stability` reads. The detector's `lateral_rms_m` is not a
    substitute, nor is the frame-acceleration observation (noisy and biased in v1).

    At reset the info adds `scenario` (`env.unwrapped.task.scenario_summary(0)`): every value
    the episode drew or was given, JSON-friendly: `params` (factors), `conicity` (None: the
    bogie's own), `primary_longitudinal_stiffness`, `primary_lateral_stiffness`, `creep_factor`,
    `damper_factor`, `axle_load`, `actuator_gain` (per channel), `failed_actuator`,
    `stuck_actuator` (None: no such fault), `stuck_command`, `start_kmh`, `end_kmh`,
    `accel_m_per_s2`, `track_position_m`, `route`, `route_copy`, `initial_offset_m`,
    `initial_yaw_rad`, `large_perturbation` and `sensor_bias` (SI, per channel; None without the
    sensor model).

    ## Arguments

    ```python
    import gymnasium as gym
    import bogie_env
    env = gym.make("Bogie/Hunting-v0", config={"speed": {"accel": 0.5}}, render_mode="rgb_array")
    ```
    `config` is a mapping or a YAML path merged into `bogie_env.envs.config.default_config()`
    (unknown keys are errors); keyword arguments override top-level keys. Important keys:
    `bogie` (preset YAML), `bogie_overrides`, `dt` (0.01 s), `speed` (start, end, accel and
    optional per-episode ranges), `track` (alignment rms 0.5 mm over 3-80 m, German high-speed
    spectrum shape), `randomize` (per-episode parameter scale ranges, e.g.
    `{"Csy": [0.5, 1.0]}`), `actuators`, `observation`, `reward`, `hunting`.
    `reset(options=...)` accepts `start_kmh`, `end_kmh`, `accel` (0-10 m/s²: the speed only
    ramps up or stays constant; speeds within the supported range, see "Speed range"), `params`
    (a mapping of scale factors) and the scenario entries (see "Bogie/Hunting-v1"); the step
    limit is the config's, so a ramp made longer by reset options is truncated there. Every bad value is a
    `ConfigError` naming the key; `randomize` ranges are checked when the env is made.
    `step()` before the first `reset()` raises `gymnasium.error.ResetNeeded`. `render_fps` is
    `1 / dt` (100 with the default 0.01 s), so recorded videos play in real time.
    The vector envs restart a finished episode with no reset options, unless
    `autoreset.reuse_options` is true: then with the options of the row's last
    `reset(options=...)` (Gymnasium vector env) or `set_options` (SB3 VecEnv), so a fixed-speed,
    fault-free study stays so across episodes.
    `variant` names a preset of `bogie_env.envs.config.VARIANTS` that `config` merges into; the
    registered ids set it: `Bogie/HuntingPassive-v0` (`passive`), `Bogie/HuntingSemiActive-v0`
    (`semi_active`), `Bogie/HuntingSlowRamp-v0` (`slow_ramp`); `Bogie/Hunting-v0` and its
    second name `Bogie/HuntingActive-v0` use the defaults.

    ## Bogie/Hunting-v1: the realistic task

    `Bogie/Hunting-v1` (variant `v1`; also `Bogie/HuntingPassive-v1`, `Bogie/HuntingSemiActive-v1`,
    `Bogie/HuntingSlowRamp-v1` at 0.1 m/s²) keeps the spaces, reward, termination and info of
    v0 and changes the world (sources in `docs/environment.md`):

    - Speed: 100-600 km/h at 1.5 m/s² (worn wheels hunt far below 300 km/h); lower speeds
      need `speed.supported_kmh` (see "Speed range").
    - Sensors (`config["sensors"]`, `bogie_env/envs/sensors.py`): every sensor observation
      (indices 0-6; the actuator forces stay exact) passes a first-order anti-alias filter
      (40 Hz) and gets a per-episode bias and white noise: frame lateral accelerometer
      80 µg/√Hz, bias 7.5 mg; yaw-rate gyro 0.008 °/s/√Hz, bias 0.2 °/s; wheelset-to-frame
      LVDTs 1 µm/√Hz, bias 62.5 µm (lateral) and 17 µrad (yaw); speed 0.1 (km/h)/√Hz, bias 2 km/h.
      Per-sample noise rms = density x √(π/2 x bandwidth). One factor scales every channel:
      `sensors.noise_scale` on the noise densities and `sensors.bias_scale` on the biases (default
      1; 0 switches the noise or the bias off, 2 doubles it), the same as editing each
      `sensors.<channel>.noise_density` / `.bias`. `observation.noise` (see above) stays 0.
      `sensors.noise_draws`: "per_channel" (v1, v2: one Box-Muller draw per channel and sample)
      or "paired" (v3, v4: both branches of one draw for two channels); the same statistics, other
      sequences.
    - Actuators: `delay_steps` = 1 (10 ms loop delay) and `rate_limit` 200 kN/s (lateral),
      400 kN m/s (yaw channels), on top of the 10 Hz lag and the saturation of v0.
    - Track: alignment at the EN 13848-5 `alert` level (`track.level`; also `intervention`,
      `immediate_action`), D1 band 3-25 m.
    - Per-episode scenario (`config["randomize"]`, named entries, `bogie_env/envs/scenario.py`):
      `conicity` [0.025, 0.3] (absolute), factors `primary_longitudinal_stiffness` and
      `primary_lateral_stiffness` [0.5, 1.5], `creep_factor` [0.5, 1] (on the Kalker
      coefficients), `damper_factor` [0.5, 1] (secondary dampers), `axle_load` [0.8, 1.2],
      `actuator_gain` [0.8, 1.25] per channel; `actuator_failure_probability` 0.05 (one channel
      gives zero force) and `actuator_stuck_probability` 0.05 (one channel holds a random command).
      `reset(options=...)` sets any of them: e.g. `{"conicity": 0.2, "failed_actuator": "frame_yaw"}`,
      `{"stuck_actuator": "frame_lateral", "stuck_command": 0.4}`, `{"actuator_gain": {"frame_yaw": 1.25}}`.
      A fault option given as None means "not given": the draw stands. `"none"` switches that
      fault off for the episode: `{"failed_actuator": "none", "stuck_actuator": "none"}`
      (`bogie_env.envs.scenario.NO_FAULTS`) is a fault-free episode whatever the probabilities;
      the other draws stay as they were. The reset info's `scenario` states what was drawn.
    - Integration: the RK4 substep meets an accuracy criterion (`integration.step_criterion =
      "accuracy"`: decay rate and frequency of every lightly damped mode within 10 %, for every
      bogie the ranges can draw), not stability alone: 10 substeps of 1 ms instead of 2 of 5 ms.

    ## Bogie/HuntingRoute-v1: curves

    `Bogie/HuntingRoute-v1` (variant `v1_route`; `Bogie/HuntingRoutePassive-v1`: `v1_route_passive`)
    is v1's world on the shipped routes (`configs/routes/`: `high-speed-7000`,
    `conventional-1500`, `s-curve`; config `route.names`, one drawn per episode, or
    `reset(options={"route": name, "route_copy": k, "start_kmh": v})`). An episode runs its route
    at a constant speed drawn from the route's range (`route.speed_kmh`; 300-350, 160-190 and
    230-260 km/h) and is truncated when the frame reaches the route's end. Curvature and cant
    enter through the track samples with the alignment irregularity. The detector and the
    lateral penalty read each wheelset's displacement about its mean over 10 m of track
    (`hunting.detrend_m`), so the quasi-static offset in a curve is not hunting. Reward:
    `progress x (1 - penalty)` with `progress = time_weight dt` (5.4 km/h per s) and the penalty
    adding `wear_weight x min(mean wear number / wear_reference, 1)` and `flange_weight x` (share of
    wheelsets in flange contact) to v1's terms (weights 0.3, 0.1, 0.1, 0.2, 0.2; reference 65 N).
    Termination also when the largest wheel Y/Q over a 2 m sliding mean exceeds 0.8
    (`curving.y_over_q_limit`). Info adds `wear_number_n` (2,), `flange_contact` (2,),
    `y_over_q`, `guiding_force_n` (2,), `curvature_1pm`, `cant_deficiency_m`, `y_over_q_exceeded`
    (`flange_contact` and `y_over_q` are the criterion fields of "Info", computed in the step;
    `guiding_force_n` is ΣY as the wheelset's force on the track, i.e. `-sum_y_n`).

    ## Version History

    - v0: initial version.
    - v1: sensor noise, bias and bandwidth; loop delay and force-rate limits; EN 13848-5 track
      levels; per-episode conicity, suspension, creep, axle load, actuator gain and faults;
      converged integration. `Bogie/HuntingRoute-v1` (curves) is a variant of v1; the other v1
      ids are unchanged bit for bit (`tests/test_v1_golden.py`).
    - v0 and v1 infos gain, at reset, `scenario` and, with `info.criterion`, the per-step
      criterion fields; reset options
      gain the fault value `"none"`; config gains `sensors.noise_scale`, `sensors.bias_scale`,
      `speed.supported_kmh`, `info.criterion` and `autoreset.reuse_options`. Trajectories are
      unchanged (`tests/test_v0_golden.py`, `tests/test_v1_golden.py`).
    - v2: v1's task with a 10-stage Taylor integrator at 2 substeps (20 right-hand sides per
      step instead of 40), chosen by the same accuracy criterion.
    - v3: v1's task with a 14-stage method designed for the bogie's spectrum, one substep (14),
      and the sensor noise drawn in pairs.
    - v4: v3 with a 12-stage method from the same design program, one substep (12). v2-v4 keep
      their bits (`tests/test_v2_v3_golden.py`, `tests/test_v4_golden.py`; evidence and speed:
      docs/studies/integrator.md, docs/performance.md).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 100}  # 1 / dt; set per instance

    def __init__(
        self,
        config: Mapping[str, Any] | str | None = None,
        render_mode: str | None = None,
        variant: str | None = None,
        **overrides: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode = {render_mode!r} is not allowed; allowed: {self.metadata['render_modes']}")
        self.task = HuntingTask(1, make_config(config, variant=variant, **overrides))
        self.max_episode_steps = self.task.max_episode_steps()
        self._episode_steps = 0
        self.action_space = self.task.action_space
        self.observation_space = self.task.observation_space
        self.render_mode = render_mode
        # one frame per step, so a recorded video plays in real time (dt = 0.01 s -> 100 fps)
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.task.config["dt"]))}
        self._renderer = None
        self._seeded = False
        self._needs_reset = True

    @property
    def config(self) -> dict:
        return self.task.config

    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.task.seed_rows(np.array([0]), [seed])
            self._seeded = True
        elif not self._seeded:
            self.task.seed_rows(np.array([0]), [int(self.np_random.integers(2**63))])
            self._seeded = True
        self.task.reset_rows(np.array([0]), options)
        self._episode_steps = 0
        self._needs_reset = False
        if self.render_mode == "human":
            self.render()
        return self.task.obs[0].copy(), {**self.task.info_dict(0), "scenario": self.task.scenario_summary(0)}

    def step(self, action):
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step(): the env has no episode yet")
        task = self.task
        task.step(action)
        self._episode_steps += 1
        obs = task.obs[0].copy()
        terminated, truncated = task.episode_end(0)
        truncated = truncated or self._episode_steps >= self.max_episode_steps
        if self.render_mode == "human":
            self.render()
        return obs, float(task.reward[0]), terminated, truncated, task.info_dict(0)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        if self._renderer is None:
            from .render import BogieRenderer

            self._renderer = BogieRenderer(self.task, self.render_mode, self.metadata["render_fps"])
        return self._renderer.render(0)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    @property
    def channel_names(self) -> tuple[str, ...]:
        return self.task.channel_names
