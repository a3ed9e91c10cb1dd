"""The classical controllers by name: the names :func:`bogie_agents.controllers.policies.load_policy` and a
residual policy's ``baseline`` (:mod:`bogie_agents.controllers.residual`) accept.

- ``passive``, ``skyhook``, ``lqr``, ``lqg``: :mod:`bogie_agents.controllers.lqr`;
- ``robust_damping``: :mod:`bogie_agents.controllers.robust`;
- ``robust_steering``: ``robust_damping`` plus the curving assist of :mod:`bogie_agents.controllers.curving_assist`.
"""

from __future__ import annotations

from .lqr import LQGController, LQRController, PassiveController, RateAwareLQGController, SkyhookController
from .curving_assist import SteeringController
from .privileged import PrivilegedController
from .robust import RobustDampingController

#: name -> controller class (each takes the env config).
CLASSICAL = {"passive": PassiveController, "skyhook": SkyhookController, "lqr": LQRController, "lqg": LQGController,
             "lqg_rate": RateAwareLQGController,
             "robust_damping": RobustDampingController, "robust_steering": SteeringController,
             "privileged": PrivilegedController}
