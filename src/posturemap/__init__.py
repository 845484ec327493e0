"""posturemap: real-time motion transitions between mocap clips with a Uniform Posture Map.

Kim, Lee, Chung, Hwang and Lee, "The Uniform Posture Map Algorithm for the Real-Time
Interactive Motion Transitions of an Articulated Body" (ICCSA 2004), implemented and extended.
"""

from .bvh import BVHError
from .errors import UserError
from .motion import Motion
from .skeleton import Skeleton

__version__ = "0.1.0"
__all__ = ["BVHError", "Motion", "Skeleton", "UserError", "__version__"]
