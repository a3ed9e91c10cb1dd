"""The evaluation protocols and their results: protocol v2/v3 (:mod:`.stability_protocol`, its
criterion :mod:`.criterion` and parts :mod:`.ramp_down`, :mod:`.curving_evaluation`), protocol v1
(:mod:`.evaluate`), Ray tasks (:mod:`.evaluation_tasks`), result tables and scores
(:mod:`.results`, :mod:`.scoreboard`, :mod:`.tables`). May import :mod:`bogie_agents.controllers`
and :mod:`bogie_agents.design` (docs/extending.md, "Code layout")."""
