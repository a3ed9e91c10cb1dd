"""The controllers: the classical ones (:mod:`.lqr`: passive, skyhook, LQR, LQG), the robust
design (:mod:`.robust`, :mod:`.robust_track`, its gain tables ``robust_gains*.json``), curving
assistance (:mod:`.curving_assist`), the residual policy (:mod:`.residual`), the registry
(:mod:`.classical`) and :func:`.policies.load_policy`. Nothing here imports the other subpackages
at module level (docs/extending.md, "Code layout")."""

#: ``--policy`` help of the commands: every name of :data:`.classical.CLASSICAL` and
#: :data:`.policies.SHIPPED` (tests/test_policy_loading.py checks), kept here so that a command's
#: ``--help`` does not import the controllers.
POLICY_HELP = ("a classical controller (passive, skyhook, lqr, lqg, lqg_rate, adaptive_lqg, adaptive_lqg_rate, "
               "robust_damping, robust_steering, mpc; privileged references: privileged, privileged_sensors, "
               "privileged_mpc, privileged_mpc_sensors), a shipped policy (pretrained, distilled, distilled_mpc, "
               "distilled_mpc_washout) or PATH (run folder or SB3 .zip, needs --trust-policy); repeatable")
