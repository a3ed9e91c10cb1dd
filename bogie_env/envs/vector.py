"""Native batched front-end: a Gymnasium ``VectorEnv``.

It steps every environment in one call of the compiled task kernel.
:class:`BogieHuntingVectorEnv` (Gymnasium 1.x, ``AutoresetMode.NEXT_STEP``): an env that
terminated or truncated is reset on the *next* ``step`` call, which returns its first
observation with reward 0, as Gymnasium's vector wrappers expect. The Stable-Baselines3
``VecEnv`` over the same task (same-step reset) is :class:`bogie_agents.training.vec_env.BogieHuntingSB3VecEnv`,
so that this module imports neither SB3 nor torch.

For the same seed, sub-env ``i`` follows exactly the trajectory of a single
``BogieHuntingEnv`` reset with ``seed + i`` (``tests/test_envs.py``).
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .config import make_config
from .task import HuntingTask


def _seeds(seed: int | Sequence[int | None] | None, n: int, rng: np.random.Generator) -> list[int]:
    if seed is None:
        return [int(s) for s in rng.integers(2**63, size=n)]
    if isinstance(seed, (int, np.integer)):
        return [int(seed) + i for i in range(n)]
    seeds = list(seed)
    if len(seeds) != n:
        raise ValueError(f"got {len(seeds)} seeds for {n} environments")
    return [int(s) if s is not None else int(rng.integers(2**63)) for s in seeds]


class BogieHuntingVectorEnv(VectorEnv):
    """N bogies in one compiled call; Gymnasium's ``VectorEnv`` with NEXT_STEP autoreset.

    Made by ``gym.make_vec("Bogie/Hunting-v0", num_envs=N, vectorization_mode="vector_entry_point")``.
    It truncates episodes itself: at the end of the ramp, or after ``max_episode_steps``
    (default: the configured ramp's length plus 10 %).

    Infos: the single env's fields as arrays over the envs (``BogieHuntingEnv``, "Info"), each
    with its ``_key`` mask; with config ``info.criterion`` the per-step criterion fields
    (``wheelset_lateral_rel_rail_m``, ``flange_contact``, ``wheel_flange_contact``, ``sum_y_n``,
    ``wheel_y_over_q``, ``y_over_q``) are computed for all envs in one compiled call. A ``reset`` and a ``step`` that restarts
    envs add ``scenario``: an object array holding each (re)started env's scenario summary
    (``HuntingTask.scenario_summary``), its ``_scenario`` mask True for those envs only.

    Autoreset: a finished env restarts with no reset options (a random speed and scenario as
    the config draws them), unless config ``autoreset.reuse_options`` is true: then with the
    options of its last ``reset(options=...)`` (``reset_mask`` aside), e.g. every episode of a
    fixed-speed, fault-free study stays at its speed and fault-free.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"], "render_fps": 100}

    def __init__(
        self,
        num_envs: int = 1,
        config: Mapping[str, Any] | str | None = None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        variant: str | None = None,
        **overrides: Any,
    ) -> None:
        self.task = HuntingTask(num_envs, make_config(config, variant=variant, **overrides))
        self.num_envs = self.task.num_envs
        self.single_action_space = self.task.action_space
        self.single_observation_space = self.task.observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode = {render_mode!r} is not allowed; allowed: {self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.task.config["dt"]))}
        self.max_episode_steps = int(max_episode_steps) if max_episode_steps else self.task.max_episode_steps()
        self._episode_steps = np.zeros(self.num_envs, dtype=np.int64)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._renderer = None
        self._seeded = False
        self._started = np.zeros(self.num_envs, dtype=bool)  # rows that have had a reset
        self._row_options: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]  # each row's last reset options

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: Mapping[str, Any] | None = None):
        """Reset every env, or with ``options={"reset_mask": mask}`` (bool, (num_envs,)) only the
        masked ones (Gymnasium's convention); the others keep their episodes. ``seed`` is an int
        (env i gets ``seed + i``), a list of per-env seeds (None: drawn), or None."""
        if seed is not None and not isinstance(seed, (int, np.integer)):
            seed = list(seed)
            if len(seed) != self.num_envs:
                raise ValueError(f"reset(seed=[...]) got {len(seed)} seeds for {self.num_envs} environments")
            super().reset(seed=None)  # the per-env list seeds the envs; np_random only fills in None entries
        else:
            super().reset(seed=seed)
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if mask is None:
            rows = np.arange(self.num_envs)
        else:
            mask = np.asarray(mask)
            if mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
                raise ValueError(
                    f"reset_mask must be a bool array of shape ({self.num_envs},); got dtype {mask.dtype}, shape {mask.shape}"
                )
            rows = np.nonzero(mask)[0]
        if seed is not None or not self._seeded:
            seeds = _seeds(seed, self.num_envs, self.np_random)
            self.task.seed_rows(rows, [seeds[i] for i in rows])
            self._seeded = True
        self.task.reset_rows(rows, options or None)
        for i in rows:
            self._row_options[i] = options
        self._episode_steps[rows] = 0
        self._autoreset[rows] = False
        self._started[rows] = True
        return self.task.obs.copy(), self._with_scenarios(self.task.batched_infos(), rows)

    def _with_scenarios(self, infos: dict[str, Any], rows: np.ndarray) -> dict[str, Any]:
        """``infos`` plus ``scenario``: an object array holding each reset row's
        ``task.scenario_summary`` (None elsewhere), masked by ``_scenario``."""
        scenario = np.full(self.num_envs, None, dtype=object)
        mask = np.zeros(self.num_envs, dtype=bool)
        for i in rows:
            scenario[i] = self.task.scenario_summary(int(i))
        mask[rows] = True
        return {**infos, "scenario": scenario, "_scenario": mask}

    def _autoreset_rows(self, rows: np.ndarray) -> None:
        """Start the next episode of finished rows: with no options, or (config
        ``autoreset.reuse_options``) with each row's last reset options."""
        if not self.task.config["autoreset"]["reuse_options"]:
            self.task.reset_rows(rows)
            return
        groups: dict[int, list[int]] = {}
        for i in rows:
            groups.setdefault(id(self._row_options[i]), []).append(int(i))
        for group in groups.values():
            self.task.reset_rows(np.array(group), self._row_options[group[0]] or None)

    def step(self, actions):
        if not self._started.all():
            raise gym.error.ResetNeeded(
                f"call reset() before step(): env(s) {np.nonzero(~self._started)[0].tolist()[:10]} have no episode yet"
            )
        self.task.step(actions)
        self._episode_steps += 1
        terminated = self.task.terminated
        truncated = self.task.truncated | (self._episode_steps >= self.max_episode_steps)
        rewards = self.task.reward.copy()
        restarting = np.nonzero(self._autoreset)[0]
        if restarting.size:  # NEXT_STEP: these finished last step; this step is their reset
            self._autoreset_rows(restarting)
            self._episode_steps[restarting] = 0
            rewards[restarting] = 0.0
            terminated[restarting] = False
            truncated[restarting] = False
        self._autoreset = terminated | truncated
        infos = self.task.batched_infos()
        if restarting.size:
            infos = self._with_scenarios(infos, restarting)
        return self.task.obs.copy(), rewards, terminated, truncated, infos

    def render(self):
        if self.render_mode is None:
            return None
        if self._renderer is None:
            from .render import BogieRenderer

            self._renderer = BogieRenderer(self.task, "rgb_array", self.metadata["render_fps"])
        return self._renderer.render(0)

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
