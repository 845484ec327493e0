"""posturemap: real-time motion transitions between mocap clips with a Uniform Posture Map.

Kim, Lee, Chung, Hwang and Lee, "The Uniform Posture Map Algorithm for the Real-Time
Interactive Motion Transitions of an Articulated Body" (ICCSA 2004), implemented and extended.

>>> import posturemap
>>> from posturemap import bvh
>>> a, b = bvh.read("walk.bvh"), bvh.read("run.bvh")            # doctest: +SKIP
>>> model = posturemap.PostureMap().fit([a, b])                 # doctest: +SKIP
>>> out = posturemap.transition(a, b, model, length=20, alpha=0.5)  # doctest: +SKIP
>>> bvh.write("walk_to_run.bvh", out)                           # doctest: +SKIP

``posturemap.transition`` is the function; its module stays importable as
``from posturemap.transition import TransitionEngine, METHODS``.
"""

from .bvh import BVHError
from .errors import UserError
from .model import MapFileError, PostureMap
from .motion import Motion
from .skeleton import Skeleton
from .transition import DEFAULT_METHOD, METHODS, TransitionEngine, transition
from .upm import UniformPostureMap

__version__ = "0.1.0"
__all__ = ["BVHError", "DEFAULT_METHOD", "METHODS", "MapFileError", "Motion", "PostureMap", "Skeleton",
           "TransitionEngine", "UniformPostureMap", "UserError", "transition", "__version__"]
