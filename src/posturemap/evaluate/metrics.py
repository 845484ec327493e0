"""Quality metrics for transitions and in-betweening: pure functions on arrays.

Conventions: quaternions ``(..., 4)`` ordered (w, x, y, z); positions in the clip's own length
unit (centimetres for Bandai); ``fps`` frames per second; time is the axis just before the
joint axis (``(N, T, J, ...)`` for a batch of N windows of T frames). Nothing is modified in
place.

In-betweening accuracy follows the LaFAN1 benchmark (Harvey et al. 2020, "Robust Motion
In-betweening"; code: ubisoft/ubisoft-laforge-animation-dataset, ``lafan1/benchmarks.py``,
``extract.py``, ``utils.py``):

- every window is put in its own frame (:func:`normalize_windows`): the root's mean
  horizontal position over the window moves to the origin, and the window is turned about
  the up axis so that the root faces a fixed direction at the last past-context frame
  (``extract.get_lafan1_set``: "Sequences around XZ = 0", ``utils.rotate_at_frame``);
- :func:`l2q`: per frame, the L2 norm of the difference of all joints' global quaternions
  (every component of every joint), averaged over frames and windows;
- :func:`l2p`: the same on global positions divided, per coordinate, by the standard deviation
  of that coordinate over training windows in the same frame (:func:`position_stats`;
  LaFAN1 subtracts the mean too, which cancels in the difference);
- :func:`npss`: LaFAN1's ``fast_npss`` on the flattened global quaternions.

The others: :func:`mpjpe` (mean per-joint position error, clip unit), :func:`weighted_skate`
(the standard foot-skate measure: horizontal foot speed weighted by closeness to the ground,
unit/s, no contact detection), :func:`foot_skate` (the older measure: speed over detected
contact steps only, which misses a foot sliding above the contact height), :func:`pose_validity`
(distance to the nearest training posture), :func:`motion_features` and
:func:`nearest_window_distance` (naturalness: distance of a window to its nearest real window)
and :func:`jerk` (third derivative of positions, unit/s^3).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..core import quat

# Foot contact thresholds (Bandai: centimetres at 30 fps); see :func:`foot_contacts`.
CONTACT_HEIGHT = 3.0
CONTACT_SPEED = 50.0
# Height scale H of :func:`weighted_skate` in leg lengths (thigh + shin): 2.5 cm on Bandai's
# 80 cm leg, the H of the standard measure (Zhang et al. 2018, "Mode-adaptive neural networks").
SKATE_HEIGHT_LEGS = 2.5 / 80.0


def align_signs(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``q`` with each quaternion negated where it lies in the other hemisphere from ``ref``.

    q, ref : ndarray (..., 4), broadcast together. Returns a new array of q's shape.
    ``q`` and ``-q`` are the same rotation; the sign consistent with ``ref`` is the one whose
    component difference is the distance between the rotations.
    """
    q = np.asarray(q, dtype=float)
    return np.where(quat.dot(q, ref)[..., None] < 0.0, -q, q)


def l2q(pred: np.ndarray, true: np.ndarray) -> float:
    """LaFAN1's global quaternion loss (L2Q).

    pred, true : ndarray (N, T, J, 4), global rotations of the rebuilt frames.
    Returns the mean over windows and frames of ``sqrt(sum_{j, c} (pred - true)^2)``, the sum
    running over all J joints and 4 components, after negating each predicted quaternion that
    lies in the other hemisphere from the truth (so a sign flip costs nothing). Unitless.
    """
    d = align_signs(pred, true) - true
    return float(np.mean(np.sqrt(np.sum(d * d, axis=(-2, -1)))))


def normalize_windows(gpos: np.ndarray, grot: np.ndarray, root: int, up: int, frame: int,
                      ref_pos: np.ndarray | None = None, ref_rot: np.ndarray | None = None):
    """Put each window in its own frame, as LaFAN1 does before measuring (see module doc).

    gpos : ndarray (N, T, J, 3), global positions; grot : ndarray (N, T, J, 4), global rotations
    root : index of the joint carrying the trajectory; up : up axis (0, 1, 2)
    frame : index in T of the frame whose facing becomes the reference (LaFAN1: the last
        past-context frame, ``n_past - 1``)
    ref_pos, ref_rot : the windows that define the frame, same shapes (default: ``gpos`` and
        ``grot`` themselves). Pass the ground truth to put a prediction in the truth's frame.

    The horizontal mean of the root over the T frames moves to the origin; the whole window
    turns about ``up`` by minus the root's heading (rotation about ``up``, by swing-twist) at
    ``frame``. Returns ``(gpos, grot)`` in that frame, new arrays of the input shapes.
    """
    ref_pos = gpos if ref_pos is None else ref_pos
    ref_rot = grot if ref_rot is None else ref_rot
    up_v = np.zeros(3)
    up_v[up] = 1.0
    shift = ref_pos[:, :, root].mean(axis=1)  # (N, 3)
    shift[:, up] = 0.0
    heading, _ = quat.heading_twist(ref_rot[:, frame, root], up_v)  # (N, 4)
    turn = quat.inv(heading)[:, None, None, :]
    pos = quat.mul_vec(turn, gpos - shift[:, None, None, :])
    rot = quat.mul(turn, grot)
    return pos, rot


def position_stats(gpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation per joint coordinate over windows and frames.

    gpos : ndarray (N, T, J, 3), global positions of training windows after
        :func:`normalize_windows`. Returns ``(mean, std)``, each (J, 3), in the unit of gpos.
    """
    flat = gpos.reshape(-1, *gpos.shape[-2:])
    return flat.mean(axis=0), flat.std(axis=0)


def l2p(pred: np.ndarray, true: np.ndarray, std: np.ndarray, eps: float = 1e-8) -> float:
    """LaFAN1's normalised global position loss (L2P).

    pred, true : ndarray (N, T, J, 3), global positions in the window frame
        (:func:`normalize_windows`); std : ndarray (J, 3) from :func:`position_stats`.
    Returns the mean over windows and frames of ``sqrt(sum_{j, c} ((pred - true) / std)^2)``.
    Unitless. A coordinate that never varies in training (``std < eps``, such as the height
    of a joint fixed at the origin) is divided by 1 instead: its difference is then 0 for any
    forward-kinematics output, where LaFAN1's formula would give 0/0.
    """
    s = np.where(std < eps, 1.0, std)
    d = (pred - true) / s
    return float(np.mean(np.sqrt(np.sum(d * d, axis=(-2, -1)))))


def mpjpe(pred: np.ndarray, true: np.ndarray) -> float:
    """Mean per-joint position error: mean Euclidean distance over all joints and frames.

    pred, true : ndarray (..., J, 3), positions in one unit; the result is in that unit.
    """
    return float(np.mean(np.linalg.norm(pred - true, axis=-1)))


def npss(pred: np.ndarray, true: np.ndarray) -> float:
    """Normalized power spectrum similarity (Gopalakrishnan et al. 2019), LaFAN1's ``fast_npss``.

    pred, true : ndarray (N, T, D), N sequences of T frames of D features (LaFAN1: the
    global quaternions of all joints, flattened; make the signs consistent first).
    Per sequence and feature: the power spectrum (square of the real part of the FFT over
    time, as in LaFAN1), normalised to sum 1, its cumulative sum; the L1 distance between
    the predicted and true cumulative spectra (an earth mover's distance); the result is
    their average weighted by the true total power. Features whose true power is 0 (a joint
    that never rotates, such as a fixed top joint) have weight 0 and are left out (LaFAN1's
    code would divide 0 by 0); a prediction with no power there counts as a flat spectrum.
    Unitless, 0 for identical spectra.
    """
    gt_power = np.square(np.real(np.fft.fft(true, axis=1)))
    pr_power = np.square(np.real(np.fft.fft(pred, axis=1)))
    gt_total = gt_power.sum(axis=1)  # (N, D)
    pr_total = pr_power.sum(axis=1)
    keep = gt_total > 0
    if not keep.any():
        return 0.0
    t_count = true.shape[1]
    gt_norm = gt_power / np.where(keep, gt_total, 1.0)[:, None, :]
    pr_norm = np.where(pr_total[:, None, :] > 0, pr_power / np.where(pr_total > 0, pr_total, 1.0)[:, None, :],
                       1.0 / t_count)
    emd = np.abs(np.cumsum(pr_norm, axis=1) - np.cumsum(gt_norm, axis=1)).sum(axis=1)  # (N, D)
    return float(np.average(emd[keep], weights=gt_total[keep]))


def horizontal_speed(pos: np.ndarray, fps: float, up: int) -> np.ndarray:
    """Speed in the horizontal plane between consecutive frames.

    pos : ndarray (..., T, K, 3), positions of K points; returns (..., T-1, K) in unit/s,
    entry ``t`` for the step from frame ``t`` to ``t + 1``.
    """
    h = [a for a in range(3) if a != up]
    step = np.diff(pos[..., h], axis=-3)
    return np.linalg.norm(step, axis=-1) * fps


def foot_contacts(pos: np.ndarray, fps: float, up: int, floor: np.ndarray,
                  height: float = CONTACT_HEIGHT, speed: float = CONTACT_SPEED) -> np.ndarray:
    """Ground contacts of foot joints, from their height and their horizontal speed.

    pos : ndarray (..., T, K, 3), global positions of K foot joints (e.g. ankles and toes)
    floor : ndarray (K,), each joint's height when planted (e.g. a low percentile over the
        training frames; Bandai: about 11.7 cm for the ankle, 4.2 cm for the toe)
    height : a joint is low when ``pos[up] < floor + height`` (default 3 cm)
    speed : and slow when its horizontal speed is below ``speed`` (default 50 cm/s)

    Returns bool (..., T-1, K): entry ``t`` is the step from frame ``t`` to ``t + 1``, in
    contact when the joint is low at both ends of the step and slow during it. The speed bound
    is generous (a planted foot moves at a few cm/s, a swinging one passes the floor at
    several m/s): it keeps the swing phase out without hiding a foot that slides.
    """
    low = pos[..., up] < np.asarray(floor) + height  # (..., T, K)
    return low[..., 1:, :] & low[..., :-1, :] & (horizontal_speed(pos, fps, up) < speed)


def foot_skate(pos: np.ndarray, fps: float, up: int, contacts: np.ndarray) -> tuple[float, int]:
    """Mean horizontal speed of foot joints over the steps where they touch the ground.

    pos : ndarray (..., T, K, 3), global foot positions; contacts : bool (..., T-1, K), e.g.
    from :func:`foot_contacts` (of this motion or of the ground truth).
    Returns ``(mean speed in unit/s, number of contact steps)``; the mean is 0 when there is
    no contact. 0 means the feet stay where they are planted.
    """
    v = horizontal_speed(pos, fps, up)[contacts]
    return (float(v.mean()) if v.size else 0.0), int(v.size)


def weighted_skate(pos: np.ndarray, fps: float, up: int, height: float, offset: np.ndarray | None = None,
                   steps: slice = slice(None)) -> np.ndarray:
    """The standard foot-skate measure: horizontal foot speed weighted by closeness to the ground.

    pos : ndarray (..., T, K, 3), global positions of K foot joints (ankles and toes) over a
        window of T frames; fps : frames per second; up : up axis
    height : H, in the unit of ``pos`` (e.g. ``SKATE_HEIGHT_LEGS`` times the leg length)
    offset : ndarray (K,), each joint's own height when planted (e.g. an ankle is higher than a
        toe; default 0): heights are measured above it
    steps : the frame steps to average over (entry ``t`` = frame ``t`` to ``t + 1``; default all)

    Per window, the ground is the lowest joint height (above its offset) over all T frames and
    K joints; per joint and step, ``h`` = the mean height above the ground at the two ends,
    ``w = clip(2 - 2 ** (h / H), 0, 1)`` (1 on the ground, 0 from H above it) and the skate
    is ``w`` times the horizontal speed. No contact is detected, so a foot sliding near the
    ground always counts. Returns ndarray (...,): the mean over the chosen steps and the K
    joints, in unit/s.
    """
    h = pos[..., up] - (0.0 if offset is None else np.asarray(offset))  # (..., T, K)
    h = h - h.min(axis=(-2, -1), keepdims=True)
    w = np.clip(2.0 - np.exp2(0.5 * (h[..., 1:, :] + h[..., :-1, :]) / height), 0.0, 1.0)
    return (w * horizontal_speed(pos, fps, up))[..., steps, :].mean(axis=(-2, -1))


def floor_penetration(pos: np.ndarray, up: int, context: np.ndarray, frames: slice) -> np.ndarray:
    """How deep feet go into the floor: per window, the mean over ``frames`` of the deepest foot
    joint's depth under the floor (0 where every foot joint is above it).

    pos : ndarray (..., T, K, 3), global positions of K foot joints over a window of T frames
    up : up axis
    context : bool (T,), the frames that say where the floor is (the real frames around a gap):
        the floor is the lowest foot joint over them, the same for every method and the truth
    frames : the frames scored (e.g. the gap's)

    Returns ndarray (...,) in the unit of ``pos``. A measure whose ground is the window's own
    lowest foot (such as :func:`weighted_skate`) counts a foot through the floor as the floor,
    and every other foot as that much higher: this one keeps the context's floor.
    """
    h = pos[..., up]  # (..., T, K)
    floor = h[..., np.asarray(context, dtype=bool), :].min(axis=(-2, -1))
    depth = np.maximum(floor[..., None] - h[..., frames, :].min(axis=-1), 0.0)
    return depth.mean(axis=-1)


def foot_float(pos: np.ndarray, up: int, context: np.ndarray, frames: slice) -> np.ndarray:
    """How far feet leave the floor together: per window, the most the lowest foot joint rises
    over ``frames`` above the highest it reaches over the ``context`` frames (0 where never).

    pos : ndarray (..., T, K, 3), global positions of K foot joints over a window of T frames
    up : up axis; context : bool (T,), the real frames around a gap; frames : the frames scored

    Returns ndarray (...,) in the unit of ``pos``. A run's flight in the context raises the bar by
    its own height. The height-weighted skate (:func:`weighted_skate`) weighs a foot by its
    closeness to the ground, so feet held in the air lower it: this measure shows them.
    """
    low = pos[..., up].min(axis=-1)  # (..., T): the lowest foot joint per frame
    bar = low[..., np.asarray(context, dtype=bool)].max(axis=-1)
    return np.maximum(low[..., frames].max(axis=-1) - bar, 0.0)


POP_FLOOR_LEGS = 5.0  # leg lengths per second (13 cm a frame at 30 fps on Bandai): a brisk walking swing's
#                       peak step, the least a transition's largest step is compared with (runner.run_cross)


def largest_step(pos: np.ndarray, frames: slice) -> np.ndarray:
    """The largest distance any joint moves from one frame to the next over ``frames``.

    pos : ndarray (..., T, J, 3), global positions; frames : the frames whose steps count (each
    with the next one inside ``frames``). Returns ndarray (...,) in the unit of ``pos``. A pop (a
    foot thrown across, a limb snapped to a pose) shows here as a step larger than the motion's
    own, where a mean over the window such as the jerk averages it away.
    """
    window = pos[..., frames, :, :]
    return np.linalg.norm(np.diff(window, axis=-3), axis=-1).max(axis=(-2, -1))


POP_ACCEL_LEGS = 40.0  # leg lengths per second squared (3.6 cm a frame squared at 30 fps on Bandai): the
#                        99th percentile of walking ankles' accelerations (38 in bandai1's walks, 54 in
#                        LaFAN1's), the least a transition's largest acceleration is compared with


def largest_acceleration(pos: np.ndarray, frames: slice) -> np.ndarray:
    """The largest acceleration of any joint over ``frames``: ``|p[t+1] - 2 p[t] + p[t-1]|``, per
    frame squared, for every frame ``t`` with both neighbours inside ``frames``.

    pos : ndarray (..., T, J, 3), global positions. Returns ndarray (...,) in the unit of ``pos``
    per frame squared. A limb set off or stopped at once (a foot thrown from rest into a step, a
    knee snapped straight) shows here where its step, no longer than the motion's own, does not.
    """
    window = pos[..., frames, :, :]
    return np.linalg.norm(np.diff(window, n=2, axis=-3), axis=-1).max(axis=(-2, -1))


def motion_features(gpos: np.ndarray, grot: np.ndarray, root: int, up: int, fps: float) -> np.ndarray:
    """Pose and velocity of every frame after the first, in the character's own frame.

    gpos : ndarray (..., T, J, 3), global positions; grot : ndarray (..., T, J, 4), global
    rotations; root : index of the joint carrying the trajectory; up : up axis.
    Per frame t >= 1, turned by minus the root's heading (about ``up``) at t: the joints'
    positions relative to the root, the root's height, and every joint's velocity from
    t - 1 to t (unit/s). Invariant to where the window is on the floor and which way it faces.
    Returns ndarray (..., T-1, 6 J + 1): ``3 J`` pose, 1 root height and ``3 J`` velocity
    columns, in the unit of ``gpos`` (velocities per second).
    """
    up_v = np.zeros(3)
    up_v[up] = 1.0
    heading, _ = quat.heading_twist(grot[..., 1:, root, :], up_v)  # (..., T-1, 4)
    turn = quat.inv(heading)[..., None, :]
    rel = quat.mul_vec(turn, gpos[..., 1:, :, :] - gpos[..., 1:, root: root + 1, :])
    vel = quat.mul_vec(turn, np.diff(gpos, axis=-3)) * fps
    lead = rel.shape[:-2]
    return np.concatenate([rel.reshape(*lead, -1), gpos[..., 1:, root, up][..., None],
                           vel.reshape(*lead, -1)], axis=-1)


def nearest_window_distance(query: np.ndarray, ref: np.ndarray, exclude: np.ndarray | None = None,
                            ref_sq: np.ndarray | None = None) -> np.ndarray:
    """Distance from each query window to its nearest reference window (naturalness).

    query : ndarray (N, D), ref : ndarray (M, D): windows as flat feature vectors in one
    normalised space; exclude : bool (N, M), pairs not to consider (e.g. a reference window
    overlapping the query's own frames), or None; ref_sq : (M,) the squared norms of ``ref``
    when already known. Returns (N,): the root mean square over the D features of the
    difference to the nearest allowed reference window (inf if none).
    """
    q, r = np.asarray(query, dtype=float), np.asarray(ref, dtype=float)
    ref_sq = (r * r).sum(1) if ref_sq is None else ref_sq
    d2 = (q * q).sum(1)[:, None] + ref_sq[None, :] - 2.0 * q @ r.T
    if exclude is not None:
        d2 = np.where(exclude, np.inf, d2)
    return np.sqrt(np.maximum(d2.min(axis=1), 0.0) / q.shape[1])


def build_posture_index(postures: np.ndarray) -> cKDTree:
    """A KD-tree over training postures (M, D) (e.g. a map's feature vectors)."""
    return cKDTree(np.asarray(postures, dtype=float))


def pose_validity(postures: np.ndarray, index: cKDTree, workers: int = -1) -> np.ndarray:
    """Distance from each posture (N, D) to the nearest training posture in ``index``.

    Same feature space as the index (the map's: logmap radians, root height in leg lengths).
    Returns (N,); small means the posture is close to one that was really captured.
    ``workers``: threads for the query (-1: all CPUs; the result does not depend on it).
    """
    d, _ = index.query(np.asarray(postures, dtype=float), k=1, workers=workers)
    return d


def jerk(pos: np.ndarray, fps: float) -> float:
    """Mean magnitude of the third time derivative of positions.

    pos : ndarray (..., T, J, 3) with T >= 4, in one length unit; the derivative is the third
    finite difference ``p[t+3] - 3 p[t+2] + 3 p[t+1] - p[t]`` times ``fps**3``. Returns the
    mean of its norm over all (T-3) steps, joints and leading axes, in unit/s^3.
    """
    d3 = np.diff(pos, n=3, axis=-3) * fps**3
    return float(np.mean(np.linalg.norm(d3, axis=-1)))
