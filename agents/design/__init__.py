"""Loop analysis and controller design: linear models of controllers (:mod:`.linear_models`), the
stability margins (:mod:`.margins`, its oracles :mod:`.margin_oracles`) and the robust
controller's design command line (:mod:`.robust_cli`). May import :mod:`bogie_agents.controllers`
(docs/extending.md, "Code layout")."""
