"""Stable-Baselines3 ``VecEnv`` over the native batched task, with same-step reset.

It steps every environment in one call of the compiled task kernel, like
:class:`bogie_env.envs.vector.BogieHuntingVectorEnv`; they differ only in how finished
episodes restart: here a finished env is reset within the same ``step_wait``; its last
observation is in ``info["terminal_observation"]`` and ``info["TimeLimit.truncated"]`` says
whether the episode was cut by the time limit. It lives with the agents because it needs SB3
(and so torch); the library's vector env does not.

For the same seed, sub-env ``i`` follows exactly the trajectory of a single
``BogieHuntingEnv`` reset with ``seed + i`` (``tests/test_envs.py``).
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from bogie_env.envs.task import HuntingTask
from bogie_env.envs.vector import _seeds


class BogieHuntingSB3VecEnv(VecEnv):
    """N bogies in one compiled call; Stable-Baselines3's ``VecEnv`` with same-step reset.

    Infos: each finished env's dict holds ``terminal_observation``, ``TimeLimit.truncated`` and
    the single env's step info (``BogieHuntingEnv``, "Info"); the others are empty (building 4096
    full dicts per step would dominate the step time). ``reset_infos[i]["scenario"]`` is env
    i's episode scenario (``HuntingTask.scenario_summary``), set at each reset and autoreset.
    Wrap it in ``VecMonitor`` for episode statistics.

    Reset options: ``set_options(...)`` before ``reset()``; the first env's options apply to
    every env. A finished env restarts with no options, unless config
    ``autoreset.reuse_options`` is true: then with the options of the last ``reset()``.
    """

    def __init__(
        self,
        num_envs: int = 1,
        config: Mapping[str, Any] | str | None = None,
        max_episode_steps: int | None = None,
        seed: int | None = None,
        **overrides: Any,
    ) -> None:
        self.task = HuntingTask(num_envs, config, **overrides)
        self.render_mode = None
        super().__init__(self.task.num_envs, self.task.observation_space, self.task.action_space)
        self.max_episode_steps = int(max_episode_steps) if max_episode_steps else self.task.max_episode_steps()
        self._episode_steps = np.zeros(self.num_envs, dtype=np.int64)
        self._actions: np.ndarray | None = None
        self._rng = np.random.default_rng(seed)
        if seed is not None:
            self.seed(seed)

    def reset(self):
        rows = np.arange(self.num_envs)
        if any(s is not None for s in self._seeds) or not getattr(self, "_seeded", False):
            self.task.seed_rows(rows, _seeds(list(self._seeds), self.num_envs, self._rng))
            self._seeded = True
        options = self._options[0] if self._options and self._options[0] else None
        self.task.reset_rows(rows, options)
        self._last_options = options  # every row's; autoreset reuses them with config autoreset.reuse_options
        self.reset_infos = [{"scenario": self.task.scenario_summary(i)} for i in range(self.num_envs)]
        self._episode_steps[:] = 0
        self._reset_seeds()
        self._reset_options()
        return self.task.obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        self.task.step(self._actions)
        self._episode_steps += 1
        terminated = self.task.terminated
        time_limit = self._episode_steps >= self.max_episode_steps
        truncated = self.task.truncated | time_limit
        dones = terminated | truncated
        rewards = self.task.reward.astype(np.float32)
        obs = self.task.obs.copy()
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        done_rows = np.nonzero(dones)[0]
        for i in done_rows:
            info = self.task.info_dict(int(i))
            info["terminal_observation"] = obs[i].copy()
            info["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            infos[i] = info
        if done_rows.size:
            reuse = self.task.config["autoreset"]["reuse_options"]
            self.task.reset_rows(done_rows, getattr(self, "_last_options", None) if reuse else None)
            for i in done_rows:
                self.reset_infos[i] = {"scenario": self.task.scenario_summary(int(i))}
            self._episode_steps[done_rows] = 0
            obs[done_rows] = self.task.obs[done_rows]
        return obs, rewards, dones, infos

    def close(self) -> None:
        pass

    # ---- the VecEnv interface for attributes of "sub-envs" -------------------------------------
    # One task serves all sub-envs. A sub-env's attributes are the task's (shared) plus any set
    # per env with set_attr; a task method that takes ``rows`` acts on the indexed sub-envs only.
    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        rows = [int(indices)] if isinstance(indices, (int, np.integer)) else [int(i) for i in indices]
        bad = [i for i in rows if not 0 <= i < self.num_envs]
        if bad:
            raise IndexError(f"env indices {bad} out of range for {self.num_envs} environments")
        return rows

    def _per_env(self) -> list[dict[str, Any]]:
        if not hasattr(self, "_env_attrs"):
            self._env_attrs: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        return self._env_attrs

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        per_env = self._per_env()
        out = []
        for i in self._indices(indices):
            if attr_name in per_env[i]:
                out.append(per_env[i][attr_name])
            elif hasattr(self.task, attr_name):
                out.append(getattr(self.task, attr_name))
            else:
                out.append(getattr(self, attr_name))
        return out

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        """Set an attribute of the indexed sub-envs. A task attribute (shared by all sub-envs) can
        only be set for all of them at once."""
        rows = self._indices(indices)
        if hasattr(self.task, attr_name):
            if sorted(rows) != list(range(self.num_envs)):
                raise ValueError(f"{attr_name!r} belongs to the task that all {self.num_envs} sub-envs share; "
                                 "set it without indices")  # fmt: skip
            setattr(self.task, attr_name, value)
            self.task._packed_step_args = None  # the step's packed arrays are rebuilt from the task's
            return
        for i in rows:
            self._per_env()[i][attr_name] = value

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        """Call a task method for the indexed sub-envs: once per index with ``rows=[i]`` if it takes
        ``rows``; otherwise (shared state) only for all sub-envs at once."""
        import inspect

        rows = self._indices(indices)
        owner = self.task if hasattr(self.task, method_name) else self
        method = getattr(owner, method_name)
        if "rows" in inspect.signature(method).parameters:
            return [method(*method_args, rows=np.array([i]), **method_kwargs) for i in rows]
        if sorted(rows) != list(range(self.num_envs)):
            raise ValueError(f"{method_name!r} acts on all {self.num_envs} sub-envs at once (it takes no rows); "
                             "call it without indices")  # fmt: skip
        result = method(*method_args, **method_kwargs)
        return [result for _ in rows]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]


class ConcatVecEnv(VecEnv):
    """Several VecEnvs with the same spaces as one: sub-envs ``0 .. n_0 - 1`` are the first's, and so
    on. It lets one training see several tasks at once (tangent track and routes, say), each
    stepping its rows in its own compiled call."""

    def __init__(self, venvs: Sequence[VecEnv]) -> None:
        if not venvs:
            raise ValueError("ConcatVecEnv needs at least one VecEnv")
        first = venvs[0]
        for venv in venvs[1:]:
            if venv.observation_space != first.observation_space or venv.action_space != first.action_space:
                raise ValueError(f"ConcatVecEnv: spaces differ ({venv.observation_space}, {venv.action_space} against "
                                 f"{first.observation_space}, {first.action_space})")  # fmt: skip
        self.venvs = list(venvs)
        self.bounds = np.cumsum([0] + [v.num_envs for v in self.venvs])
        super().__init__(int(self.bounds[-1]), first.observation_space, first.action_space)

    def reset(self):
        return np.concatenate([venv.reset() for venv in self.venvs])

    def step_async(self, actions: np.ndarray) -> None:
        for k, venv in enumerate(self.venvs):
            venv.step_async(actions[self.bounds[k]:self.bounds[k + 1]])

    def step_wait(self):
        parts = [venv.step_wait() for venv in self.venvs]
        obs = np.concatenate([p[0] for p in parts])
        rewards = np.concatenate([p[1] for p in parts])
        dones = np.concatenate([p[2] for p in parts])
        infos = [info for p in parts for info in p[3]]
        return obs, rewards, dones, infos

    def seed(self, seed: int | None = None):
        return [s for k, venv in enumerate(self.venvs) for s in venv.seed(None if seed is None else seed + int(self.bounds[k]))]

    def close(self) -> None:
        for venv in self.venvs:
            venv.close()

    def _split(self, indices) -> list[tuple[VecEnv, list[int]]]:
        rows = range(self.num_envs) if indices is None else ([int(indices)] if isinstance(indices, (int, np.integer))
                                                              else [int(i) for i in indices])  # fmt: skip
        out = []
        for k, venv in enumerate(self.venvs):
            local = [i - int(self.bounds[k]) for i in rows if self.bounds[k] <= i < self.bounds[k + 1]]
            if local:
                out.append((venv, local))
        return out

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [v for venv, local in self._split(indices) for v in venv.get_attr(attr_name, local)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        for venv, local in self._split(indices):
            venv.set_attr(attr_name, value, None if len(local) == venv.num_envs else local)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        return [v for venv, local in self._split(indices)
                for v in venv.env_method(method_name, *method_args, indices=local, **method_kwargs)]  # fmt: skip

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [v for venv, local in self._split(indices) for v in venv.env_is_wrapped(wrapper_class, local)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
