"""The trajectory side of a transition: clips split into trajectory and posture, and B's alignment.

Every frame is split into a *trajectory* (root horizontal position, heading about the up
axis) and a *posture* (root height, root tilt, local rotations). Root alignment turns B about
the up axis and moves it so that it continues A: its start lies where A's root, moving at the
mean of the two clips' seam velocities, gets to in ``length + 1`` frames, facing A's heading
advanced by the mean turning rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core import kernels, quat
from ..core.joints import leg_chains, leg_toes
from ..core.motion import Motion, up_vector
from ..learn.features import root_global


@dataclass(frozen=True, eq=False)
class Track:
    """A clip split into trajectory and posture, computed once per clip.

    Attributes
    ----------
    motion : the clip
    gpos : (F, 3) global root position
    heading : (F,) root heading about the up axis, radians, continuous over time
    rots : (F, J, 4) local rotations, with the root's replaced by its tilt
    features : (F, D) posture vectors for a map, or None
    feet : (F, n_legs, 3) global ankle positions (for foot locking)
    toes : (F, n_legs, 3) global positions of each leg's toe (:func:`posturemap.core.joints.leg_toes`:
        its ankle where it has none), for the foot lock's floor and its planted toes at the seams
    """

    motion: Motion
    gpos: np.ndarray
    heading: np.ndarray
    rots: np.ndarray
    features: np.ndarray | None
    feet: np.ndarray
    toes: np.ndarray


def heading_of(q: np.ndarray, up: int) -> np.ndarray:
    """Angle (radians) of rotations ``q (..., 4)`` about the up axis (they must be pure turns)."""
    return 2.0 * np.arctan2(q[..., 1 + up], q[..., 0])


def rotate_about_up(v: np.ndarray, angle, up: int) -> np.ndarray:
    """Vectors ``v (..., 3)`` turned by ``angle`` (radians, right-handed) about the up axis; an
    array of angles broadcasts over the leading axes."""
    a, b = (up + 1) % 3, (up + 2) % 3
    if isinstance(angle, float):  # a Python or numpy float64: math's cos, without a ufunc call (numpy's
        # values here; within an ulp where numpy has its own SIMD cos)
        c, s = math.cos(angle), math.sin(angle)
    else:
        c, s = np.cos(angle), np.sin(angle)
    out = np.array(v, dtype=float)
    va, vb = v[..., a], v[..., b]
    out[..., a] = c * va - s * vb
    out[..., b] = s * va + c * vb
    return out


def make_track(motion: Motion, root: int, up: int, rest: np.ndarray, space=None) -> Track:
    """Split a clip into trajectory and posture (see :class:`Track`)."""
    grot, gpos = root_global(motion, root)
    head_q, tilt = quat.heading_tilt(grot, up_vector(up), rest)
    heading = np.unwrap(heading_of(head_q, up))
    rots = motion.rotations.copy()
    rots[:, root] = tilt
    feats = space.encode(motion) if space is not None else None
    chains = leg_chains(motion.skeleton)
    feet = toes = np.zeros((len(motion), 0, 3))
    if chains:
        grot_all, gpos_all = np.empty(motion.rotations.shape), np.empty(motion.positions.shape)
        kernels.fk(motion.skeleton.parents, motion.rotations, motion.positions, grot_all, gpos_all)
        feet = gpos_all[:, [c[2] for c in chains]]
        toes = gpos_all[:, leg_toes(motion.skeleton, chains)]
    return Track(motion, gpos, heading, rots, feats, feet, toes)


def alignment(a: Track, b: Track, a_end: int, b_start: int, length: int, up: int) -> tuple[float, np.ndarray]:
    """Turn (radians about up) and translation (3,) that make B continue A."""
    h1, h2 = (up + 1) % 3, (up + 2) % 3
    d = length + 1.0
    a0, b1 = max(a_end - 1, 0), min(b_start + 1, len(b.gpos) - 1)
    pa, pa0, pb, pb1 = a.gpos[a_end], a.gpos[a0], b.gpos[b_start], b.gpos[b1]
    wa = a.heading[a_end] - a.heading[a0]
    wb = b.heading[b1] - b.heading[b_start]
    dtheta = float(a.heading[a_end] + 0.5 * (wa + wb) * d - b.heading[b_start])
    c, s = math.cos(dtheta), math.sin(dtheta)
    # B's seam velocity and start, turned by dtheta in the horizontal plane (h1, h2).
    vb1, vb2 = pb1[h1] - pb[h1], pb1[h2] - pb[h2]
    vb1, vb2 = c * vb1 - s * vb2, s * vb1 + c * vb2
    sb1, sb2 = c * pb[h1] - s * pb[h2], s * pb[h1] + c * pb[h2]
    shift = np.zeros(3)
    shift[h1] = pa[h1] + 0.5 * (pa[h1] - pa0[h1] + vb1) * d - sb1
    shift[h2] = pa[h2] + 0.5 * (pa[h2] - pa0[h2] + vb2) * d - sb2
    return dtheta, shift


def aligned(track: Track, start: int, dtheta: float, shift: np.ndarray, chain: np.ndarray, root: int,
            up: int) -> Motion:
    """Frames ``start:`` of a clip, turned by ``dtheta`` about up and moved by ``shift``.

    ``chain`` holds the root's ancestors (top first), whose rotations carry the heading.
    """
    m = track.motion
    rots = track.rots[start:].copy()
    positions = m.positions[start:].copy()
    gpos = rotate_about_up(track.gpos[start:], dtheta, up) + shift
    kernels.compose_root(chain, root, up, rots, positions, gpos, track.heading[start:] + dtheta)
    return Motion(m.skeleton, rots, positions, m.fps)
