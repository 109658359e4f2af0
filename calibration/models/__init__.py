"""Fitted kinematic models: the base and its registry, the model files, and each model kind.

=============  ==========================================================================================
module         holds
=============  ==========================================================================================
``base``       :class:`KinematicModel` (pose, blocks, Jacobians, casadi), :class:`Block`, the registry,
               ``save_model`` / ``load_model``
``constant``   ``constant``: one POE geometry
``pi``         ``pi``: geometry + tool rotation + mass-free compliance + structural deflection (77 parameters)
``cdc``        ``cdc``: the ``pi`` layout with its geometric block interpolated over (q2, q3)
``physics``    ``physics``: POE geometry + fitted effects (:mod:`calibration.physics`)
``diagnosed``  ``diagnosed``: a ``pi`` or ``cdc`` model + effects
``rebased``    ``rebased``: a model of any kind with base and tool-marker corrections (:mod:`calibration.rebase`)
=============  ==========================================================================================

Only the base and ``constant`` are imported here; a kind's module is imported when a file of that kind is
loaded (or by whoever builds one), which registers it.
"""

from calibration.models.base import (
                                     MODEL_KIND_MODULES,
                                     SCHEMA,
                                     Block,
                                     KinematicModel,
                                     load_model,
                                     poe_from_dict,
                                     poe_to_dict,
                                     save_model,
)
from calibration.models.constant import ConstantModel

__all__ = ["Block", "ConstantModel", "KinematicModel", "MODEL_KIND_MODULES", "SCHEMA", "load_model", "poe_from_dict",
           "poe_to_dict", "save_model"]
