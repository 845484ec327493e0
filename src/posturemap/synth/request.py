"""One transition request: the methods, the parameters, their defaults and their validation.

The Python API (:func:`posturemap.transition`, :meth:`TransitionEngine.generate`), the CLI
(``posturemap transition``) and the studio server (``POST /api/transition``) all build a
:class:`TransitionRequest` and call :meth:`TransitionRequest.resolved`, so one set of defaults
and one set of checks hold everywhere. A refused field raises :class:`RequestError`, which
names the field as the API does (``a_end``); the CLI shows it as its option (``--a-end``), the
server as the JSON field with status 422.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import sys
from dataclasses import dataclass

from ..errors import UserError


def _is_bool(v) -> bool:
    """A Python or numpy bool (numpy is not imported here: ``posturemap --help`` loads none)."""
    np = sys.modules.get("numpy")
    return isinstance(v, bool) or (np is not None and isinstance(v, np.bool_))


@dataclass(frozen=True)
class Method:
    """What a method needs: a posture map (``keyed``: ``alpha`` steers it) and ``key_at``."""

    summary: str
    keyed: bool = False
    key_at: bool = False


# Every method, in the order they are offered. The engine has one implementation per name.
METHOD_INFO = {
    "auto": Method("the default: retrieval at every gap length (held out, ahead of the spline on short gaps too, "
                   "but on the shortest at 60-120 fps, 0.03-0.17 s, where its foot lock costs L2P: up to 19% "
                   "behind the spline without it); the name stays what `posturemap bench` finds best", keyed=True),
    "retrieval": Method("real motion from the map's library (between clips, A's continuation spliced into B's "
                        "arrival when no one segment fits), seams blended, feet planted", keyed=True),
    "upm": Method("the paper's key posture from the four class maps, through a B-spline", keyed=True, key_at=True),
    "upm-path": Method("as upm, the key along the map graph's shortest path", keyed=True, key_at=True),
    "upm-valid": Method("several keys, each projected into the map's valid region", keyed=True, key_at=True),
    "spline": Method("cubic Hermite spline matching values and velocities at both seams"),
    "slerp": Method("SLERP of every rotation, LERP of the root"),
    "damped": Method("SLERP/LERP plus each seam's velocity, carried for its motion's own time scale "
                     "(0.05-0.33 s; a joint reaching for the other seam's pose, until it gets there), then "
                     "let go; a joint swinging at both seams swings on in phase"),
    "inertialize": Method("B's start plus a decaying offset from A's end (Bollo 2016)"),
}
METHODS = tuple(METHOD_INFO)
KEYED = tuple(m for m, info in METHOD_INFO.items() if info.keyed)  # need a map; alpha steers them
KEY_POSTURE = tuple(m for m, info in METHOD_INFO.items() if info.key_at)  # through key postures
DEFAULT_METHOD = "auto"  # chosen by `posturemap bench`: see the README
DEFAULT_LENGTH = 20  # in-between frames (the paper's 20)
DEFAULT_ALPHA = 0.5
MAX_LENGTH = 10_000
FIELDS = ("length", "alpha", "method", "key_at", "a_end", "b_start", "align", "foot_lock")


class RequestError(UserError):
    """A request field the engine refuses; ``field`` names it as the API does."""

    def __init__(self, field: str, what: str):
        super().__init__(field, what)
        self.field = field


def describe(v) -> str:
    """A value as a message shows it: short, whatever its size or type (JSON names for JSON kinds)."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, numbers.Real):
        v = int(v) if isinstance(v, numbers.Integral) else float(v)  # numpy scalars as plain numbers
        text = repr(v) if not isinstance(v, int) or abs(v) < 10 ** 40 else f"a {len(str(abs(v)))}-digit number"
        return text if len(text) <= 40 else text[:37] + "..."
    if isinstance(v, str):
        return "a string"
    if isinstance(v, (list, tuple)):
        return "an array"
    if isinstance(v, dict):
        return "an object"
    return type(v).__name__


def _whole(field: str, v, lo: int, hi: int, where: str | None = None) -> int:
    if _is_bool(v) or not isinstance(v, numbers.Real):
        raise RequestError(field, f"must be a whole number, got {describe(v)}")
    if not isinstance(v, numbers.Integral):  # a float (numpy's too) that is a whole number
        if not (math.isfinite(v) and v == int(v)):
            raise RequestError(field, f"must be a whole number, got {describe(v)}")
    v = int(v)
    if not lo <= v <= hi:
        raise RequestError(field, f"frame {describe(v)} is outside {where} (frames {lo}..{hi})" if where
                           else f"must be between {lo} and {hi}, got {describe(v)}")
    return v


def frame_index(field: str, v, count: int, where: str) -> int:
    """``v`` as a frame of a clip of ``count`` frames (``where`` names the clip), or a
    :class:`RequestError` on ``field``."""
    return _whole(field, v, 0, count - 1, where)


def _flag(field: str, v) -> bool:
    if not _is_bool(v):
        raise RequestError(field, f"must be true or false, got {describe(v)}")
    return bool(v)


@dataclass(frozen=True)
class TransitionRequest:
    """The parameters of one transition (the clips are named or passed separately).

    Attributes
    ----------
    length : in-between frames, 1..``MAX_LENGTH`` (paper: 20)
    alpha : the control parameter in [0, 1]: for the key methods 0 keys near A's posture and
        1 near B's; for retrieval 0 prefers motion that continues A, 1 motion that arrives in B
    method : one of :data:`METHODS` (default :data:`DEFAULT_METHOD`)
    key_at : position of the key among the new frames, 1..length (default ``max(1, length // 2)``;
        the paper's 10th of 20); used by :data:`KEY_POSTURE` methods
    a_end : last frame of A used (default: A's last frame)
    b_start : first frame of B used
    align : move and turn B to continue A; False leaves B's root exactly where it is
        (in-betweening)
    foot_lock : keep planted feet still, toes out of the floor and swinging toes clear of it in
        the new frames (:mod:`posturemap.synth.feet`)
    """

    length: int = DEFAULT_LENGTH
    alpha: float = DEFAULT_ALPHA
    method: str = DEFAULT_METHOD
    key_at: int | None = None
    a_end: int | None = None
    b_start: int = 0
    align: bool = True
    foot_lock: bool = True

    @classmethod
    def from_fields(cls, raw: dict) -> TransitionRequest:
        """A request from a mapping of field names (e.g. a JSON body); absent or None fields take
        their defaults. Other keys are ignored (the caller checks them). Not yet validated."""
        return cls(**{f: raw[f] for f in FIELDS if raw.get(f) is not None})

    def replace(self, **fields) -> TransitionRequest:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **fields)

    @classmethod
    def of(cls, request: TransitionRequest | None = None, **fields) -> TransitionRequest:
        """``request`` (default: the defaults) with ``fields`` on top: what :meth:`generate
        <posturemap.synth.engine.TransitionEngine.generate>` and
        :func:`~posturemap.synth.engine.transition` take. A ``TypeError`` for anything else than a
        request (a dict of fields, say)."""
        if request is None:
            return cls(**fields)  # what replacing the defaults' fields makes, in one step
        if not isinstance(request, cls):
            raise TypeError(f"request must be a TransitionRequest, got {type(request).__name__} "
                            "(give its fields as keywords: length=..., alpha=...)")
        return request.replace(**fields) if fields else request

    def resolved(self, len_a: int, len_b: int, *, max_length: int = MAX_LENGTH, names: tuple[str, str] | None = None
                 ) -> TransitionRequest:
        """The request checked against clips of ``len_a`` and ``len_b`` frames, defaults filled in.

        Raises :class:`RequestError` naming the first field at fault (types first, then ranges:
        a 309-digit number is refused without being converted). ``names`` (A's, B's) go into
        the messages about frames outside a clip.
        """
        method = self.method
        if not isinstance(method, str) or method not in METHOD_INFO:
            got = repr(method[:40]) if isinstance(method, str) else describe(method)
            raise RequestError("method", f"unknown method {got} (choose from {', '.join(METHODS)})")
        length = _whole("length", self.length, 1, max_length)
        key_at = _whole("key_at", max(1, length // 2) if self.key_at is None else self.key_at, 1, length)
        a_name, b_name = (f" {n!r}" for n in names) if names else ("", "")
        a_end = _whole("a_end", len_a - 1 if self.a_end is None else self.a_end, 0, len_a - 1, f"clip A{a_name}")
        b_start = _whole("b_start", self.b_start, 0, len_b - 1, f"clip B{b_name}")
        alpha = self.alpha
        if _is_bool(alpha) or not isinstance(alpha, numbers.Real):
            raise RequestError("alpha", f"must be a number between 0 and 1, got {describe(alpha)}")
        if not (0 <= alpha <= 1 and math.isfinite(alpha)):  # range first: a 309-digit int has no float
            raise RequestError("alpha", f"must be between 0 and 1, got {describe(alpha)}")
        return TransitionRequest(length, float(alpha), method, key_at, a_end, b_start,
                                 _flag("align", self.align), _flag("foot_lock", self.foot_lock))

    @property
    def keyed(self) -> bool:
        """Whether the method needs a posture map."""
        return METHOD_INFO[self.method].keyed
