"""The classical controllers by name: the names :func:`bogie_agents.controllers.policies.load_policy` and a
residual policy's ``baseline`` (:mod:`bogie_agents.controllers.residual`) accept.

- ``passive``, ``skyhook``, ``lqr``, ``lqg``, ``lqg_rate``: :mod:`bogie_agents.controllers.lqr`;
- ``robust_damping``: :mod:`bogie_agents.controllers.robust`;
- ``robust_steering``: ``robust_damping`` plus the curving assist of :mod:`bogie_agents.controllers.curving_assist`;
- ``adaptive_lqg``, ``adaptive_lqg_rate``: :mod:`bogie_agents.controllers.adaptive` (told no conicity: estimates it online);
- ``privileged``: :mod:`bogie_agents.controllers.privileged` (the reference told the true scenario; not a baseline);
- ``privileged_mpc``: :mod:`bogie_agents.controllers.mpc` (the same with hard force and rate limits; not a baseline);
- ``privileged_sensors``, ``privileged_mpc_sensors``: the two references told the true scenario but seeing only the
  sensors through a Kalman filter (what the sensors cost the headroom; not baselines);
- ``mpc``: :mod:`bogie_agents.controllers.mpc` (the same MPC on the sensors, told the conicity class only: a baseline).
"""

from __future__ import annotations

from .adaptive import AdaptiveLQGController, AdaptiveRateLQGController
from .curving_assist import SteeringController
from .lqr import LQGController, LQRController, PassiveController, RateAwareLQGController, SkyhookController
from .mpc import MPCReference, SensorMPC, SensorMPCReference
from .privileged import PrivilegedController, SensorPrivilegedController
from .robust import RobustDampingController

#: name -> controller class (each takes the env config).
CLASSICAL = {"passive": PassiveController, "skyhook": SkyhookController, "lqr": LQRController, "lqg": LQGController,
             "lqg_rate": RateAwareLQGController, "adaptive_lqg": AdaptiveLQGController,
             "adaptive_lqg_rate": AdaptiveRateLQGController,
             "robust_damping": RobustDampingController, "robust_steering": SteeringController,
             "privileged": PrivilegedController, "privileged_mpc": MPCReference,
             "privileged_sensors": SensorPrivilegedController, "privileged_mpc_sensors": SensorMPCReference,
             "mpc": SensorMPC}
