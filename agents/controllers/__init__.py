"""The controllers: the classical ones (:mod:`.lqr`: passive, skyhook, LQR, LQG), the robust
design (:mod:`.robust`, :mod:`.robust_track`, its gain tables ``robust_gains*.json``), curving
assistance (:mod:`.curving_assist`), the residual policy (:mod:`.residual`), the registry
(:mod:`.classical`) and :func:`.policies.load_policy`. Nothing here imports the other subpackages
at module level (docs/extending.md, "Code layout")."""
