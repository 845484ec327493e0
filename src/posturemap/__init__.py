"""posturemap: real-time motion transitions between mocap clips with a Uniform Posture Map.

Kim, Lee, Chung, Hwang and Lee, "The Uniform Posture Map Algorithm for the Real-Time
Interactive Motion Transitions of an Articulated Body" (ICCSA 2004), implemented and extended.

>>> import posturemap
>>> from posturemap import bvh
>>> a, b = bvh.read("walk.bvh"), bvh.read("run.bvh")            # doctest: +SKIP
>>> model = posturemap.PostureMap().fit([a, b])                 # doctest: +SKIP
>>> out = posturemap.transition(a, b, model, length=20, alpha=0.5)  # doctest: +SKIP
>>> bvh.write("walk_to_run.bvh", out)                           # doctest: +SKIP

The package's folders are its architecture (``docs/architecture.md``): ``core`` (quaternions,
skeletons, motions), ``io`` (files), ``learn`` (the maps), ``synth`` (transitions), ``evaluate``
(the benchmark) and ``web`` (the studio). The names below are the public API; ``bvh``,
``gltf`` and ``preview`` are the reader/writer modules.
"""

import importlib

__version__ = "0.1.0"
# Public names and the module that defines each, imported on first use: ``import posturemap``
# (and so ``posturemap --help``) loads no numpy; the first name used loads its module.
_EXPORTS = {"BVHError": "io.bvh", "UserError": "errors", "MapFileError": "io.mapfile",
            "PostureMap": "learn.model", "Motion": "core.motion", "resample": "core.motion",
            "Skeleton": "core.skeleton",
            "DEFAULT_METHOD": "synth.request", "METHODS": "synth.request", "TransitionEngine": "synth.engine",
            "transition": "synth.engine", "TransitionRequest": "synth.request", "RequestError": "synth.request",
            "UniformPostureMap": "learn.upm", "MotionLibrary": "synth.library"}
_MODULES = {"bvh": "io.bvh", "gltf": "io.gltf", "preview": "io.preview"}  # ``from posturemap import bvh``
__all__ = sorted(_EXPORTS) + sorted(_MODULES) + ["__version__"]


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    elif name in _MODULES:
        value = importlib.import_module(f"{__name__}.{_MODULES[name]}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

