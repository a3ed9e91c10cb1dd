"""The learner's bound on `bogie train`: the same PPO on the recipe's envs and on a free env.

    PYTHONPATH=. python studies/train_learner_bound.py --config configs/agents/ppo_v1.yaml --rounds 3

Per round, in one process and one after the other: ``PPO.learn`` of the config's recipe (its
policy, hyperparameters, wrappers, odd actor, ``torch_threads``) for ``--timesteps`` steps on
the recipe's own VecEnvs (``train.make_vec_envs``: the ramp and the routes, the residual's
baseline and features), and on a VecEnv with the same spaces and number of envs whose step
costs nothing (zero observations and rewards, never done) under the same VecMonitor and
VecNormalize. No evaluation or checkpoint callbacks in either. The free env's rate is what the
learner (policy inference, rollout buffer, gradient steps) allows with an env that costs
nothing: no change to the env can make training faster than that. Each learner is warmed by one
rollout first (numba's cache, torch's first calls). Compare the ratio within a round.
"""

from __future__ import annotations

import argparse
import copy
import json
import time

import numpy as np


def free_vec_env(like):
    """A VecEnv with ``like``'s spaces and number of envs whose step costs nothing."""
    from stable_baselines3.common.vec_env import VecEnv

    class FreeVecEnv(VecEnv):
        def __init__(self) -> None:
            super().__init__(like.num_envs, like.observation_space, like.action_space)
            self._obs = np.zeros((like.num_envs, *like.observation_space.shape), dtype=like.observation_space.dtype)
            self._reward = np.zeros(like.num_envs, dtype=np.float32)
            self._done = np.zeros(like.num_envs, dtype=bool)
            self._infos = [{} for _ in range(like.num_envs)]

        def reset(self):
            return self._obs.copy()

        def step_async(self, actions) -> None:
            pass

        def step_wait(self):
            return self._obs.copy(), self._reward.copy(), self._done.copy(), [dict(i) for i in self._infos]

        def close(self) -> None:
            pass

        def get_attr(self, attr_name, indices=None):
            return [None] * self.num_envs

        def set_attr(self, attr_name, value, indices=None) -> None:
            pass

        def env_method(self, method_name, *args, indices=None, **kwargs):
            return [None] * self.num_envs

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False] * self.num_envs

        def seed(self, seed=None):
            return [None] * self.num_envs

    return FreeVecEnv()


def learner(config: dict, env):
    """The recipe's PPO on ``env`` (as ``train._train_locked`` builds it, without callbacks)."""
    from stable_baselines3 import PPO

    from bogie_agents.controllers.residual import odd_actor
    from bogie_agents.training.train import _policy_kwargs

    model = PPO(config.get("policy", "MlpPolicy"), env, seed=int(config.get("seed", 0)), device="cpu",
                policy_kwargs=_policy_kwargs(config), **copy.deepcopy(config.get("hyperparams") or {}))  # fmt: skip
    if (config.get("residual") or {}).get("features") == "washed_out":
        odd_actor(model)
    return model


def timed_learn(model, steps: int) -> float:
    start = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/agents/ppo_v1.yaml")
    parser.add_argument("--timesteps", type=int, default=262144)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    import torch
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from bogie_agents.training.train import load_run_config, make_vec_envs, total_envs, vecnormalize_kwargs

    config = load_run_config(args.config, None)
    torch.set_num_threads(int(config.get("torch_threads", 1)))
    real, eval_env = make_vec_envs(config, int(config.get("seed", 0)))
    eval_env.close()
    free = VecNormalize(VecMonitor(free_vec_env(real)), **vecnormalize_kwargs(config))
    models = {"recipe": learner(config, real), "free env": learner(config, free)}
    rollout = int(config["hyperparams"]["n_steps"]) * total_envs(config)
    for model in models.values():
        timed_learn(model, rollout)
    rows = []
    for r in range(args.rounds):
        rates = {name: args.timesteps / timed_learn(model, args.timesteps) for name, model in models.items()}
        rows.append({"round": r + 1, **rates, "free / recipe": rates["free env"] / rates["recipe"]})
        if not args.json:
            print(f"round {r + 1}: recipe {rates['recipe'] / 1e3:.1f} k env-steps/s, free env {rates['free env'] / 1e3:.1f} k, "
                  f"free / recipe {rows[-1]['free / recipe']:.2f}", flush=True)  # fmt: skip
    real.close()
    if args.json:
        print(json.dumps({"config": args.config, "timesteps": args.timesteps, "rounds": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
