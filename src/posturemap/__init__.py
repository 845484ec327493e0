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

import importlib
import sys
import types

__version__ = "0.1.0"
# Public names and the module that defines each, imported on first use: ``import posturemap``
# (and so ``posturemap --help``) loads no numpy; the first name used loads its module.
_EXPORTS = {"BVHError": "bvh", "UserError": "errors", "MapFileError": "model", "PostureMap": "model",
            "Motion": "motion", "Skeleton": "skeleton", "DEFAULT_METHOD": "transition", "METHODS": "transition",
            "TransitionEngine": "transition", "UniformPostureMap": "upm", "MotionLibrary": "library"}
__all__ = sorted(_EXPORTS) + ["transition", "__version__"]


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """The package's module type: ``posturemap.transition`` is always the function.

    Importing the submodule ``posturemap.transition`` makes Python set the package attribute of
    that name to the module; the setter below keeps the name for the function instead.
    """

    @property
    def transition(self):
        return importlib.import_module(f"{__name__}.transition").transition

    @transition.setter
    def transition(self, value):
        pass  # the import system recording the submodule: it stays in sys.modules


sys.modules[__name__].__class__ = _Package
