"""Fitted kinematic models: the base and its registry, the model files, and each model kind.

=============  ==========================================================================================
module         holds
=============  ==========================================================================================
``base``       :class:`KinematicModel` (pose, blocks, Jacobians, casadi, to/from a dict)
``registry``   kind -> class and kind -> module (imports nothing of the models)
``files``      ``save_model`` / ``load_model``, checked on load by ``checks``
``guard``      the extrapolation guard a model carries (its region)
``urdf``       the URDF export of a model's constant geometry
``constant``   ``constant``: one POE geometry
``pi``         ``pi``: geometry + tool rotation + mass-free compliance + structural deflection (77 parameters)
``cdc``        ``cdc``: the ``pi`` layout with its geometric block interpolated over (q2, q3)
``physics``    ``physics``: POE geometry + fitted effects (:mod:`calibration.physics`)
``diagnosed``  ``diagnosed``: a ``pi`` or ``cdc`` model + effects
``rebased``    ``rebased``: a model of any kind with base and tool-marker corrections (:mod:`calibration.frames.rebase`)
=============  ==========================================================================================

Only the base and ``constant`` are imported here; a kind's module is imported when a file of that kind is
loaded (or by whoever builds one), which registers it.
"""

from calibration.models.base import SCHEMA, KinematicModel
from calibration.models.constant import ConstantModel
from calibration.models.files import load_model, save_model
from calibration.models.registry import KIND_MODULES

__all__ = ["ConstantModel", "KinematicModel", "KIND_MODULES", "SCHEMA", "load_model", "save_model"]
