"""The classical controllers by name: the names :func:`bogie_agents.policies.load_policy` and a
residual policy's ``baseline`` (:mod:`bogie_agents.residual`) accept.

- ``passive``, ``skyhook``, ``lqr``, ``lqg``: :mod:`bogie_agents.controllers`;
- ``robust_damping``: :mod:`bogie_agents.robust`;
- ``robust_steering``: ``robust_damping`` plus the curving assist of :mod:`bogie_agents.curving_assist`;
- ``adaptive_lqg``: :mod:`bogie_agents.adaptive` (told no conicity: estimates it online).
"""

from __future__ import annotations

from .adaptive import AdaptiveLQGController
from .controllers import LQGController, LQRController, PassiveController, SkyhookController
from .curving_assist import SteeringController
from .robust import RobustDampingController

#: name -> controller class (each takes the env config).
CLASSICAL = {"passive": PassiveController, "skyhook": SkyhookController, "lqr": LQRController, "lqg": LQGController,
             "robust_damping": RobustDampingController, "robust_steering": SteeringController, "adaptive_lqg": AdaptiveLQGController}
