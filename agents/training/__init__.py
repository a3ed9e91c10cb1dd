"""Training SB3 agents (:mod:`.train`), hyperparameter search (:mod:`.tune`) and the SB3 VecEnv
(:mod:`.vec_env`). May import :mod:`bogie_agents.controllers` and :mod:`bogie_agents.evaluation`
(docs/extending.md, "Code layout")."""
