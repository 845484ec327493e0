"""Foot-skate cleanup: keep planted feet still during a transition (two-bone IK on the legs).

The paper leaves the "skidding effect between ground and foot" open. Here, after the
in-between frames are made:

1. each ankle's height and speed tell when it is on the ground (in the frames around the seams
   and in the new frames), or the retrieved segment's contacts say so;
2. every run of ground frames gets one spot: A's last foot position if the run starts at A's
   end with the foot planted there, B's first if it ends at B's start with the foot planted,
   otherwise the foot's position in the middle of the run. Whether a foot is planted at a seam
   is judged against that clip's own floor (its lowest ankle over ``FLOOR_S``). A foot planted
   all through a gap, on A's spot at one end and B's at the other, makes a step between them in
   the middle of the run (lifted, over ``STEP_S`` seconds) instead of jumping, where the spots
   lie at most ``STEP_MOST`` apart (farther, no standing foot's step makes it, and the run is
   not held: the motion glides the foot there); so does a run
   held to one seam's spot that lies farther than ``MAX_DRIFT[0]`` from the foot's other end
   (where it lands, or lifts off), rather than dragging the foot there. A run that reaches a
   seam where that clip's foot is not planted is let go over its last (or first) ``STEP_S``
   (the whole run where it is not longer than that by two frames). Where the legs are
   interpolated (no retrieved contacts), a foot planted at both seams on spots at most
   ``MAX_DRIFT[1]`` apart, which the motion keeps under a step's lift and within
   ``MAX_DRIFT[0]`` of the line between them, is held through the whole gap and steps once,
   from A's spot to B's: an interpolation glides it between the two stances, low over the
   floor (a leg it lifts, as in a kick, is left to it); so is a foot that retrieved contacts
   hold all through the gap. Where two such feet or more must move
   farther than ``STAND_STEP``, they step one after another, each in its own part of the gap,
   the farthest first (:func:`stance_windows`): a person changes stance by stepping, not by
   hopping;
3. in a run the ankle is moved onto its spot (height kept), and the foot turns about its toe,
   not its ankle: where the motion rolls the foot up onto its toe or turns it, the ankle moves
   over the toe, which stays where it was at the run's reference frame (the first new frame for
   a run on A's spot, the last for one on B's, the middle for one on its own; across a step,
   from the first frame's to the last's). Held by the ankle, the toe slid back as the heel rose
   and swung round as the foot turned: between two clips, 41% of the skate at 0.5 s was a held
   foot's toe, and the toes carry nearly all the skate (the ankles stand higher than the height
   weight's reach). The foot's offset is the spot (less the toe's turn) minus where the motion
   put the ankle, its length softly limited where the spot lies far from the foot
   (``MAX_DRIFT``: the foot is dragged rather than the leg stretched). Between runs, while the
   foot is in the air, the offset passes smoothly (a smoothstep between the runs' offsets, and
   their rates carried ``CARRY_S`` at most) from one run's to the next, and from and to zero at
   A's and B's frames: the correction a planted foot needs is spread over the whole swing, not
   made in a few frames before and after it. Where a swing is too short for its change of offset at ``PASS_SPEED``
   or ``PASS_ACCEL`` (two blended segments, or a splice, whose stances lie one or two frames
   apart on spots far from each other; a run dragged far from where B puts the foot), the runs
   let go of their ends until it is not, a run left shorter than ``PASS_LEAST_S`` goes whole,
   and the freed frames lift the foot as a step does (:func:`pace_passes`): the foot had jumped
   20-25 cm a frame twice, then, at the pace alone, set off at two to five times a walking
   ankle's acceleration and came down for a frame between two passes. A toe planted at a seam
   whose foot no run holds there (the heel up, or
   the retrieved segment's foot in another phase) stays on its spot while the new frames keep it
   low, up to ``SEAM_TOE_S`` and half the gap, and no longer than lets its offset pass on at
   ``SEAM_TOE_CATCH`` (the foot is not thrown across in a few frames): otherwise it slid off in
   the first frames. So does one whose run from the seam ends within the swinging toe's lift fade
   there (``CLEAR_FADE_S``), from where the run leaves it: the foot rolls off its toe instead of
   sweeping it away low, a sweep whose lift, crammed into that fade, bent a straight knee at once;
4. a swinging foot clears the floor: while it is in the air, its toe (where the foot has a toe
   joint: :func:`posturemap.core.joints.leg_toes`) is kept at least
   ``TOE_CLEAR`` leg lengths above the floor once it moves at ``CLEAR_SPEED[1]`` leg lengths per
   second, less in proportion below (nothing under ``CLEAR_SPEED[0]``), or as high as the motion
   library's own toes keep at that speed in nine frames of ten where that is higher
   (:func:`clearance_curve`: performers and rigs differ). Blends of real segments
   (and interpolation) can drag a toe along the floor at walking speed, which real feet do not
   do; the foot is raised by the shortfall, spread smoothly over ``CLEAR_S`` seconds on each side
   (:func:`clearance_lift`). No toe stays under the floor, held or not: a retrieved stance can
   put a planted foot a few centimetres into it (a held foot's lift fades in at the seams over
   ``2r + 1`` frames, ``r = CLEAR_S * fps``, so a gap shorter than ``4r + 1`` frames gets part of
   it only; a swinging toe's, over ``CLEAR_FADE_S``). The floor is where feet stand: the lowest
   toe over A's last ``FLOOR_S`` seconds and B's first (a stance in any gait), so a toe that dips
   under it is lifted out rather than taken for the floor;
5. a two-bone IK on thigh and shin puts the ankle on the moved position (:func:`hinge_ik`):
   the knee turns about its axis (:func:`knee_axes`: its own plane's normal where it is bent;
   nearly straight, the leg's hinge, ``KNEE_HINGE``, the bending planes over the gap in the
   hips' frame, turned toward the toes), then the leg swings about the hip onto the line to the
   goal. Its bend is signed about that axis (:func:`knee_angles`), so a knee passes through
   straight instead of flipping across it: a knee bent back (a performer standing
   over-straightened) asked for more bend goes forward through straight (:func:`signed_bend`).
   Bent by the size of its bend about its plane of the moment, a nearly straight knee swung
   sideways from frame to frame, and one bent back was bent further back and then flipped
   forward at once: CMU-rig walks joined pair by pair at 60 fps popped a knee in 41 of 110
   transitions (docs/clip-pairs.md). The last ``SOFT_REACH`` of the leg's reach is approached
   softly, so a spot near the end of the reach bends the knee smoothly instead of snapping it
   straight. Before it, the lock's turn of each knee (its goal's bend less the motion's own) is
   bounded in acceleration by ``KNEE_ACCEL`` over the whole gap (:func:`knee_bounded`): near
   full extension the bend goes as the square root of the leg's shortening, and a foot lifted
   from a straight leg bent the knee 38 degrees in one frame. The foot keeps its global
   orientation (so the toe moves as the ankle does: the offsets above already turn it about
   the toe).

Legs are found by name, else in the hierarchy (:func:`posturemap.core.joints.leg_chains`);
thresholds in leg lengths (:mod:`posturemap.core.joints`).
"""

from __future__ import annotations

import numpy as np

from ..core import kernels, quat
from ..core.joints import CONTACT_HEIGHT, CONTACT_SPEED, leg_length, leg_toes
from ..core.skeleton import Skeleton
from . import hinges, rest

MAX_DRIFT = (0.2, 0.4)  # leg lengths: a planted foot is held on its spot while the spot lies within
#                           the first of where the motion put the foot; farther, it is moved ever
#                           less toward it, never past the second (soft_limit): dragged, not stretched
STEP_S = 0.3  # seconds of the step between two spots of one run (A's and B's, or a seam's spot and
#               where the foot lands or lifts off far from it), and of a run let go at a seam
STEP_MOST = 1.0  # leg lengths: a foot planted at both seams on spots farther apart is not held through the
#                  gap (no step of a standing foot makes it; held, its spot crossed the gliding foot
#                  and the softly limited pull swapped sides: 35 cm a frame twice)
STEP_LIFT = 0.1  # leg lengths (8 cm on Bandai): the step's highest lift
STEP_RISE = 0.2  # a step lifts the foot by this share of its way beyond STAND_STEP (STEP_LIFT at most):
#                  real feet planted at both ends of a gap and moved 0.1-0.2 leg lengths between rise
#                  0.5-3 cm (the ankle's median, gaps of 0.5-1 s), 0.4-1 leg lengths 4-8 cm (bandai1,
#                  LaFAN1); a quarter second or less, hardly at all (step_lift)
STEP_RISE_S = 0.5  # seconds: a gap shorter than this (A's last frame to B's first) lifts its steps by
#                    STEP_RISE times its share of this (step_rise): real feet hardly rise in 0.2 s
STEP_LAG = 0.2  # of a step's frames: the foot rises in place over the first fifth, comes down in place
#                  over the last, and travels in between (travelling from the first frame, low, it slid)
STAND_STEP = 0.05  # leg lengths (4 cm on Bandai): feet held all through the gap whose spots lie
#                    farther apart than this step one after another (stance_windows); a step lifts the
#                    foot by step_rise of its way beyond this (STEP_LIFT at most): a shorter shift slides
IK_EPS = 1e-5  # the two-bone IK keeps the thigh-ankle distance this far inside [0, thigh + shin]
SOFT_REACH = 0.05  # the lock's IK approaches the last 5% of the leg's reach softly (soft_limit)
KNEE_ACCEL = 135.0  # radians per second^2: the lock's change of a knee's bend accelerates at most this
#                    (knee_bounded; walking knees' own bend accelerates under it in 97.7% of frames, bandai1)
KNEE_HINGE = 0.2  # the IK bends a knee about its own plane's normal and the leg's hinge, the two
#                   weighing the same where the knee's sine is this (knee_axes): a straight leg's
#                   plane is noise
HINGE_SURE = 0.0052  # (sine 0.17 cubed: knees bent 20 degrees) leg_hinge's normals weigh at least this
#                      much of the legs' sizes to say which way the hinge points without the toes
KNEE_THROUGH = 3.0  # a knee bent back is bent forward once the lock asks for this many times its back
#                     bend, through straight between (signed_bend)
TOE_CLEAR = 0.03  # leg lengths (2.4 cm on Bandai): a swinging toe's least height above the floor at
#                   full speed; real toes keep it: 79-97% of bandai1's toe samples at 0.3-8 leg lengths
#                   per second are at least as high as CLEAR_SPEED asks (CMU 01_01's are higher)
CLEAR_SPEED = (0.25, 2.5)  # leg lengths per second: no clearance below the first, full from the second
# A motion library's own toes raise the clearance (clearance_curve): per speed bin (leg lengths per
# second, edges CLEAR_BINS) the CLEAR_PERCENTILE-th percentile of its toes' heights above the floor
# under them (their lowest within FLOOR_S), counted in bins of CLEAR_HEIGHTS (leg lengths).
CLEAR_BINS = (0.25, 0.5, 1.0, 1.5, 2.5, 4.0, 8.0)
CLEAR_HEIGHTS = np.linspace(0.0, 0.1, 51)
CLEAR_PERCENTILE = 10.0
CLEAR_MIN_SAMPLES = 30  # a speed bin with fewer toe samples takes the slower bin's height
CLEAR_S = 0.1  # seconds: the lift reaches its height this long before the shortfall and leaves it after
CLEAR_FADE_S = 0.05  # seconds (at least two frames): a swinging toe's lift fades in over this at each seam
SEAM_TOE_S = 0.2  # seconds: a toe planted at a seam is held there at most this long while the new frames keep it low
SEAM_TOE_GAP = 2  # frames left free between a seam's held toe and a run held after it (the offsets pass between)
SEAM_TOE_CATCH = 1.0  # leg lengths per second: the most a released toe's offset passes on at (it ends its hold sooner)
PASS_SPEED = 3.0  # leg lengths per second (2.4 m/s on Bandai): the fastest a held foot's correction
#                   passes between two runs on average (a walking swing's pace); a shorter stretch
#                   between them is widened by letting go of the runs' ends (pace_passes)
PASS_ACCEL = 40.0  # leg lengths per second^2: the pass's peak acceleration at most (the 99th percentile
#                    of walking ankles' accelerations: 38 in bandai1, 54 in LaFAN1)
PASS_LEAST_S = 0.1  # seconds: a run the widening leaves shorter is let go entirely (no hop between two passes)
CARRY_S = 0.3  # seconds: a run's rate of correction carried into the free frames this long at most (swing_offsets)
FLOOR_S = 0.5  # seconds of A's end and of B's start whose lowest toe is the floor (a stance in any gait);
#               the engine's seam floors, each clip's lowest ankle there, say whether a seam's foot is planted


def _compiled():
    """The compiled kernels once this process uses numba (:func:`posturemap.core.kernels.compiled`),
    else None: then the numpy code below runs (it is also the reference the kernel is tested against)."""
    return kernels.compiled() if kernels.backend() == "numba" else None


def soft_limit(x, start, limit):
    """``x`` up to ``start``; beyond it ``start + room * (1 - exp(-(x - start) / room))`` with
    ``room = limit - start``: it meets the line with slope 1 at ``start`` and approaches
    ``limit`` without reaching it. Where ``limit <= start``, ``x`` itself. Arrays broadcast.

    The lock uses it twice: for the thigh-ankle distance the IK aims at (soft IK: ``start`` the
    larger of the ankle's own distance and ``1 - SOFT_REACH`` of the leg's reach, ``limit`` the
    reach; a target near the end of the reach bends the knee smoothly instead of snapping it
    straight, where the knee's angle changes fastest with the distance), and for how far a
    planted foot is moved (``MAX_DRIFT``).
    """
    room = limit - start
    ok = (x > start) & (room > 0)
    excess = np.where(ok, x - start, 0.0) / np.where(ok, room, 1.0)
    return np.where(ok, start + room * -np.expm1(-excess), x)


def two_bone_ik(a, b, c, t, a_gr, b_gr, a_lr, b_lr, eps=1e-5, soft=0.0, hinge=0.0):
    """Local rotations of joints a (thigh) and b (shin) that put c (ankle) on target t.

    Positions (N, 3), global rotations ``a_gr``/``b_gr`` and local rotations ``a_lr``/``b_lr``
    (N, 4). Returns the new ``(a_lr, b_lr)``. ``soft`` > 0: the last ``soft`` of the leg's reach
    is approached softly (:func:`soft_limit`; a target there is reached a little short).

    ``hinge`` 0: the knee bends in its current plane (Holden's formulation). ``hinge`` > 0: the
    knee bends about :func:`knee_axes` (its plane's normal and the leg's hinge, weighing the
    same at a sine of ``hinge``; the hinge: the normals of the N frames summed in the hips'
    frame, :func:`leg_hinge`) to
    the bend :func:`signed_bend` asks for the target's distance, and the leg swings about the
    hip onto the target's line (:func:`hinge_ik`): a nearly straight knee bends toward the
    leg's hinge, not about the noise of its plane, and a knee bent back bends forward only
    through straight. A knee bent sideways keeps its sideways part, so a target beyond the
    reach that leaves is reached a little short (1 - cos of that part).
    """
    if hinge <= 0:
        return _bend(a, b, c, t, a_gr, b_gr, a_lr, b_lr, eps, soft, _unit_rows(np.cross(c - a, b - a)))
    axes = knee_axes(a, b, c, a_gr, a_lr, leg_hinge(a, b, c, a_gr, a_lr), hinge)
    theta0, psi = knee_angles(a, b, c, axes)
    thigh, shin = np.linalg.norm(b - a, axis=-1), np.linalg.norm(c - b, axis=-1)
    dist = np.linalg.norm(t - a, axis=-1)
    if soft > 0:
        full = knee_reach(np.zeros(len(a)), thigh, shin, psi)
        dist = soft_limit(dist, np.maximum(np.linalg.norm(c - a, axis=-1), (1.0 - soft) * full), full)
    turn = signed_bend(theta0, bend_for_reach(dist, thigh, shin, psi)) - theta0
    return hinge_ik(a, b, c, t, a_gr, b_gr, a_lr, b_lr, axes, turn, eps)


def leg_hinge(a, b, c, a_gr, a_lr, toe=None) -> np.ndarray:
    """The leg's hinge (3,) in the hips' frame (the thigh's parent's), unit (0 where every frame's
    leg is straight): the knee's bending planes' normals of the N frames (hip ``a``, knee ``b``,
    ankle ``c``, (N, 3); the thigh's global and local rotations ``a_gr``/``a_lr``) summed there,
    each weighed by its sine squared (the angle at the hip): a few frames bent forward outweigh
    many bent back a little (a knee straightened past straight, as CMU-rig walkers stand: 40
    frames bent back 7 degrees outweighed 4 bent 40 degrees forward, and the hinge pointed
    backward). With ``toe`` (N, 3), the toe joint's positions, and little to go on (the sum's
    length under ``HINGE_SURE`` of the legs' sizes: frames bent 20 degrees on average, or
    fewer bent more), the hinge is turned about where a knee bent about it goes toward the toes,
    as a knee bends; frames bent further say which way themselves (a kneeling leg, its toes
    behind the ankle, kept its hinge). Summed in the thigh's own frame, the normals turned with
    the thigh about its bone, which no position shows and a rig's clips set as they please
    (CMU-rig walks: a knee's plane 130-150 degrees from that hinge for whole steps)."""
    frame = quat.mul(a_gr, quat.inv(a_lr))
    normal = np.cross(c - a, b - a)
    size2 = np.sum((c - a) ** 2, axis=-1) * np.sum((b - a) ** 2, axis=-1)
    sine2 = np.sum(normal**2, axis=-1) / np.maximum(size2, 1e-300)
    total = quat.mul_vec(quat.inv(frame), normal * sine2[:, None]).sum(axis=0)
    hinge = _unit_rows(total)
    if toe is not None and np.linalg.norm(total) < HINGE_SURE * np.sqrt(size2).sum() and np.sum(
            np.cross(quat.mul_vec(frame, np.broadcast_to(hinge, a.shape)), c - a) * (toe - c)) < 0:
        hinge = -hinge
    return hinge


def knee_axes(a, b, c, a_gr, a_lr, hinge: np.ndarray, weight: float) -> np.ndarray:
    """Each frame's axis (N, 3; unit, normal to the thigh; 0 where there is none) the lock bends
    the knee about: the knee's plane's normal, weighed by the square of its sine (the angle at
    the hip) and by how far it lies on the hinge's side (the cosine of the angle between them,
    0 from a right angle on), plus ``weight`` cubed times the leg's ``hinge``
    (:func:`leg_hinge`, in the hips' frame), each times the leg's size, less the sum's part
    along the thigh. A knee bent forward bends in its own plane (sine ``weight``, 0.2: about 23
    degrees of bend, weighs as the hinge); a straight leg's plane is noise, and its knee bends
    about the hinge: bent about its plane, the knee swung sideways from one frame to the next
    (the bench's cross-clip pairs: the knees' jerk in the lock's frames 21,000 cm/s^3 over the
    unlocked motion's on average, up to 205,000). Weighed by the sine alone, a knee 5 degrees
    from straight, its plane flipping as it passed through, still turned the axis by 14 degrees
    in a frame, and a lifted knee bent 95 degrees with it swung 5 cm sideways (CMU-rig walks at
    60 fps). A knee bent back adds nothing: its normal, against the hinge, cancelled it at about
    23 degrees back, where the axis flipped over and the bend read about it jumped from -23 to
    +23 degrees (a cold review). So the axis turns with the motion, through straight too, and
    the bend read about it does not jump."""
    frame = quat.mul(a_gr, quat.inv(a_lr))
    size = np.linalg.norm(c - a, axis=-1) * np.linalg.norm(b - a, axis=-1)
    normal = np.cross(c - a, b - a)
    along = quat.mul_vec(frame, np.broadcast_to(hinge, a.shape))
    sine = np.linalg.norm(normal, axis=-1) / np.maximum(size, 1e-300)
    side = np.maximum(np.sum(_unit_rows(normal) * along, axis=-1), 0.0)
    h = normal * (sine**2 * side)[:, None] + weight**3 * size[:, None] * along
    e1 = _unit_rows(b - a)
    h = h - np.sum(h * e1, axis=-1, keepdims=True) * e1
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, h / np.maximum(norm, 1e-300), 0.0)


def knee_angles(a, b, c, axes) -> tuple[np.ndarray, np.ndarray]:
    """The knee's bend about ``axes`` (N, 3; unit, normal to the thigh: :func:`knee_axes`) and its
    sideways part, radians (N,) each: the bend the shin turns through about the axis from the
    thigh's line (:func:`posturemap.synth.hinges.signed_bends`; negative bent back), and the
    shin's angle out of the plane normal to the axis (which that turn keeps)."""
    shin = c - b
    theta = hinges.signed_bends(b - a, shin, axes)
    psi = np.arcsin(np.clip(np.sum(shin * axes, axis=-1) / np.maximum(np.linalg.norm(shin, axis=-1), 1e-300),
                            -1.0, 1.0))
    return theta, psi


def knee_reach(bend, thigh, shin, psi):
    """The hip-ankle distance of a leg bent ``bend`` about its axis with sideways part ``psi``
    (:func:`knee_angles`); arrays broadcast."""
    return np.sqrt(np.maximum(thigh**2 + shin**2 + 2.0 * thigh * shin * np.cos(psi) * np.cos(bend), 0.0))


def bend_for_reach(dist, thigh, shin, psi):
    """The bend about the axis (0 straight, up to pi; unsigned) that puts the ankle ``dist`` from
    the hip (:func:`knee_reach`'s inverse; clipped to what the sideways part lets it reach)."""
    cos = (dist**2 - thigh**2 - shin**2) / np.maximum(2.0 * thigh * shin * np.cos(psi), 1e-300)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def signed_bend(theta0, need):
    """The bend about the knee's axis (signed, :func:`knee_angles`) the lock gives a knee bent
    ``theta0`` whose ankle needs the unsigned bend ``need`` (:func:`bend_for_reach`); arrays
    broadcast. A knee bent forward: ``need``. A knee bent back by ``back = -theta0``: straightened
    toward 0 while ``need <= back`` (``-need``), bent forward once ``need >= KNEE_THROUGH * back``
    (``need``), and between those through straight at twice the rate (``2 need - 3 back``: the
    ankle short of its goal by up to 3 / 6 / 11 / 25 mm for a knee bent back 5 / 7 / 10 / 15
    degrees, 1 m legs, as the square of the back bend; a cold review). Bent back
    further, as the unsigned bend did, a knee bent back 7 degrees and asked for 13 went to -13;
    asked for 14, bent forward it jumped 27 degrees in a frame (CMU-rig walks at 60 fps: the
    lock's knees popped in 28 of 110 transitions between two clips, up to 5x the clips' largest
    acceleration)."""
    theta0, need = np.broadcast_arrays(np.asarray(theta0, dtype=float), np.asarray(need, dtype=float))
    back = np.maximum(-theta0, 0.0)
    between = -back + (KNEE_THROUGH + 1.0) / (KNEE_THROUGH - 1.0) * (need - back)
    return np.where(need <= back, -need, np.where(need >= KNEE_THROUGH * back, need, between))


def hinge_ik(a, b, c, t, a_gr, b_gr, a_lr, b_lr, axes, turn, eps=1e-5):
    """Local rotations of the thigh and shin (as :func:`two_bone_ik`'s) with the knee's bend about
    ``axes`` (N, 3; unit: :func:`knee_axes`) increased by ``turn`` (N,; radians), the shin turned
    about the axis through the knee, then the leg swung about the hip by the shortest arc from
    the hip-ankle line onto the hip-target one: the ankle lands on that line at
    :func:`knee_reach` of the new bend. A thigh or shin of no length (``eps``) cannot bend: that
    leg is left as it is."""
    rigid = np.minimum(np.linalg.norm(b - a, axis=-1), np.linalg.norm(c - b, axis=-1)) <= eps
    turn = np.where(rigid | (np.linalg.norm(axes, axis=-1) == 0), 0.0, turn)  # no axis: a straight leg, no hinge
    r1 = quat.from_axis_angle(quat.mul_vec(quat.inv(b_gr), axes), -turn)  # in the shin's frame
    c1 = b + quat.mul_vec(quat.from_axis_angle(axes, -turn), c - b)
    swing = np.where(rigid, 0.0, np.arccos(np.clip(np.sum(_unit_rows(c1 - a) * _unit_rows(t - a), axis=-1), -1.0, 1.0)))
    r2 = quat.from_axis_angle(quat.mul_vec(quat.inv(a_gr), _unit_rows(np.cross(c1 - a, t - a))), swing)
    return quat.mul(a_lr, r2), quat.mul(b_lr, r1)


def _unit_rows(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _bend(a, b, c, t, a_gr, b_gr, a_lr, b_lr, eps, soft, axis0):
    """:func:`two_bone_ik`'s plain IK (``hinge`` 0): the knee bent about ``axis0`` (unit, world;
    the bending plane's normal) to the target's distance, then the hip-ankle line turned onto it.
    The knee is turned by the difference of its bend's size and the target's, so a knee bent
    back about ``axis0`` and asked to bend a little more is bent further back, and forward only
    once asked for twice its bend, at once: the lock bends about :func:`knee_axes` by a signed
    bend instead (:func:`hinge_ik`)."""
    def angle(u, v):
        return np.arccos(np.clip(np.sum(_unit_rows(u) * _unit_rows(v), axis=-1), -1.0, 1.0))

    lab = np.linalg.norm(b - a, axis=-1)
    lcb = np.linalg.norm(b - c, axis=-1)
    lat = np.linalg.norm(t - a, axis=-1)
    if soft > 0:
        lat = soft_limit(lat, np.maximum(np.linalg.norm(c - a, axis=-1), (1.0 - soft) * (lab + lcb)), lab + lcb)
    # A thigh or shin of no length (a rig whose offsets are zero) cannot bend: that leg is left as it is.
    rigid = np.minimum(lab, lcb) <= eps
    lab, lcb = np.where(rigid, 1.0, lab), np.where(rigid, 1.0, lcb)
    lat = np.clip(lat, eps, lab + lcb - eps)
    ac_ab_0, ba_bc_0, ac_at_0 = angle(c - a, b - a), angle(a - b, c - b), angle(c - a, t - a)
    ac_ab_1 = np.where(rigid, ac_ab_0, np.arccos(np.clip((lcb**2 - lab**2 - lat**2) / (-2 * lab * lat), -1.0, 1.0)))
    ba_bc_1 = np.where(rigid, ba_bc_0, np.arccos(np.clip((lat**2 - lab**2 - lcb**2) / (-2 * lab * lcb), -1.0, 1.0)))
    ac_at_0 = np.where(rigid, 0.0, ac_at_0)
    axis1 = _unit_rows(np.cross(c - a, t - a))
    r0 = quat.from_axis_angle(quat.mul_vec(quat.inv(a_gr), axis0), ac_ab_1 - ac_ab_0)
    r1 = quat.from_axis_angle(quat.mul_vec(quat.inv(b_gr), axis0), ba_bc_1 - ba_bc_0)
    r2 = quat.from_axis_angle(quat.mul_vec(quat.inv(a_gr), axis1), ac_at_0)
    # r0 (and the knee's r1) set the reach along the old thigh-ankle line, then r2 turns that
    # line onto the target; in the thigh's local frame the later rotation stands on the left.
    return quat.mul(a_lr, quat.mul(r2, r0)), quat.mul(b_lr, r1)


def knee_bounded(goal: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, axes: np.ndarray, soft: float,
                 accel: float) -> tuple[np.ndarray, np.ndarray]:
    """The lock's turn of each knee about its axis (L,; radians, :func:`hinge_ik`'s ``turn``),
    bounded so that it accelerates at most ``accel`` (radians per frame squared), and which
    frames the bound moved (L,) bool.

    ``a``, ``b``, ``c`` (L, 3): the hip (thigh joint), knee and ankle as the motion has them;
    ``goal`` the ankle's goals, the ankle itself where the lock leaves the leg; ``axes`` (L, 3)
    :func:`knee_axes`; ``soft``: the IK's ``SOFT_REACH`` (the goal's distance soft-limited
    toward the leg's reach about its axis). The turn asked is :func:`signed_bend` of the goal's
    distance (:func:`bend_for_reach`) less the motion's own bend (:func:`knee_angles`), 0 in
    the clips' frames beside the new ones; it is moved as little as
    :func:`~posturemap.synth.rest.rest_bounded` finds so that its second differences stay within
    ``accel``, A's last frame's and B's first included (there, the first and the last new frame's
    turn itself), and the knee bent no
    further back than the motion's nor past pi. A bow's straight leg, its foot held while the
    hips sank into the next clip, bent the knee 0.13 radians at once: the knee set off at 5 cm a
    frame squared (30 fps) from A's still frames; a nearly straight leg whose carried offset had
    2.4 cm left at the last new frame bent its knee 7 cm off B's, which it snapped to at 9 cm a
    frame squared. (The ankle then lands on the goal's line from the hip at the bounded bend's
    reach: held feet at the seams move along it, a millimetre or two.)

    Near full extension the bend goes as the square root of the leg's shortening: a held spot
    half a centimetre nearer the hip than the motion's nearly straight leg had its ankle bent the
    knee 10 degrees, and a foot lifted from a straight leg into a pass bent it 38 degrees in
    one frame. Relaxed, the knee starts to bend a few frames earlier, the held heel rising a
    little off its spot as a real heel does before the foot leaves the floor.
    """
    thigh = np.linalg.norm(b - a, axis=-1)  # each frame's own (a blend of two clips' bones may differ)
    shin = np.linalg.norm(c - b, axis=-1)
    if min(thigh.min(), shin.min()) <= IK_EPS:  # a rigid leg: nothing to bend (the IK leaves it as it is)
        return np.zeros(len(goal)), np.zeros(len(goal), dtype=bool)
    theta0, psi = knee_angles(a, b, c, axes)
    full = knee_reach(0.0, thigh, shin, psi)
    dist = np.linalg.norm(goal - a, axis=-1)
    if soft > 0:
        dist = soft_limit(dist, np.maximum(np.linalg.norm(c - a, axis=-1), (1.0 - soft) * full), full)
    inner = signed_bend(theta0, bend_for_reach(dist, thigh, shin, psi)) - theta0
    turn = rest.rest_bounded(inner, accel, np.minimum(-theta0, 0.0), np.pi - theta0)
    return turn, np.abs(turn - inner) > 1e-9


def slower_step(x: np.ndarray) -> np.ndarray:
    """How far points move at each frame: per frame of ``x`` (F, ..., 3) the shorter of its two
    steps, to the frame before and to the frame after (the one step at either end; 0 for a
    single frame), shape (F, ...).

    A foot that lifts off or touches down at a frame stands still on one side of it; the
    central difference gives it half the next step, more of the swing's speed the lower the
    frame rate (with it, a toe's least height at 0.5-1 leg lengths per second read 0.012 leg
    lengths from LaFAN1 at 24 fps and 0.016 at 60: the lift asked less of a toe the fewer the
    frames; so, 0.023 and 0.020)."""
    if len(x) < 2:
        return np.zeros(x.shape[:-1])
    step = np.linalg.norm(np.diff(x, axis=0), axis=-1)
    return np.concatenate([step[:1], np.minimum(step[1:], step[:-1]), step[-1:]])


def toe_height_counts(toes: np.ndarray, up: int, fps: float, body: float) -> np.ndarray:
    """How high one clip's toes are at each speed: counts (len(CLEAR_BINS) - 1, len(CLEAR_HEIGHTS)
    - 1) of toe samples by horizontal speed (leg lengths per second, each frame's shorter step,
    :func:`slower_step`, as :func:`clearance_lift` measures it) and height above the floor under
    them (leg lengths; the floor of a frame is the lowest of the toes within ``FLOOR_S`` seconds
    of it, as the lock's floor is a stance's lowest toe; heights above the last bin count in it).
    Speeds outside ``CLEAR_BINS`` are not counted. ``toes`` (F, K, 3): the toe joints' global positions.
    Counts of several clips add up (a library's: :func:`clearance_curve`)."""
    counts = np.zeros((len(CLEAR_BINS) - 1, len(CLEAR_HEIGHTS) - 1))
    if len(toes) < 2 or toes.shape[1] == 0:
        return counts
    from scipy.ndimage import minimum_filter1d

    r = max(1, round(FLOOR_S * fps))
    h = toes[..., up]
    floor = minimum_filter1d(h.min(axis=1), size=2 * r + 1, mode="nearest")
    height = np.clip((h - floor[:, None]) / body, 0.0, CLEAR_HEIGHTS[-1] * (1.0 - 1e-9))
    flat = np.ones(3)
    flat[up] = 0.0
    speed = slower_step(toes * flat) * fps / body
    counts += np.histogram2d(speed.ravel(), height.ravel(), bins=(np.asarray(CLEAR_BINS), CLEAR_HEIGHTS))[0]
    return counts


def clearance_curve(counts: np.ndarray) -> np.ndarray:
    """The least height (leg lengths) a swinging toe keeps at the speeds of ``CLEAR_BINS``, from
    the toe heights of a library's clips (:func:`toe_height_counts`, summed): per speed bin the
    ``CLEAR_PERCENTILE``-th percentile of its heights (linear within a height bin). A bin with
    fewer than ``CLEAR_MIN_SAMPLES`` samples takes the slower bin's value (0 for the slowest).
    Returns (len(CLEAR_BINS) - 1,), the heights at :func:`clearance_speeds`."""
    counts = np.asarray(counts, dtype=float)
    out = np.zeros(len(counts))
    for i, row in enumerate(counts):
        total = row.sum()
        if total < CLEAR_MIN_SAMPLES:
            out[i] = out[i - 1] if i else 0.0
            continue
        cum = np.concatenate([[0.0], np.cumsum(row)]) / total
        out[i] = float(np.interp(CLEAR_PERCENTILE / 100.0, cum, CLEAR_HEIGHTS))
    return out


def clearance_speeds() -> np.ndarray:
    """The speeds (leg lengths per second) of a :func:`clearance_curve`'s heights: the middle of
    each bin of ``CLEAR_BINS``."""
    edges = np.asarray(CLEAR_BINS, dtype=float)
    return 0.5 * (edges[1:] + edges[:-1])


def clearance_need(speed: np.ndarray, clear: float, curve: np.ndarray | None = None) -> np.ndarray:
    """How high (leg lengths) a swinging toe moving at ``speed`` (leg lengths per second) must be:
    ``clear`` times ``(v - v0) / (v1 - v0)`` clipped to [0, 1] (``CLEAR_SPEED`` = (v0, v1)), or
    where a library's own toes keep higher (``curve``, :func:`clearance_curve`), their height:
    linear between :func:`clearance_speeds`, from 0 at ``CLEAR_BINS[0]``, the fastest bin's
    beyond it. ``clear`` 0 (a foot without a toe joint) asks for nothing."""
    need = clear * np.clip((np.asarray(speed, dtype=float) - CLEAR_SPEED[0]) / (CLEAR_SPEED[1] - CLEAR_SPEED[0]),
                           0.0, 1.0)
    if curve is None or clear == 0.0:
        return need
    xs = np.concatenate([[CLEAR_BINS[0]], clearance_speeds()])
    return np.maximum(need, np.interp(speed, xs, np.concatenate([[0.0], curve])))


def _clearance_table(curve: np.ndarray | None, body: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """A :func:`clearance_curve` for the compiled lock: the speeds (length unit per frame, from
    ``CLEAR_BINS[0]``) and heights (length unit, from 0) :func:`clearance_need` interpolates
    between; empty arrays for no curve."""
    if curve is None:
        return np.zeros(0), np.zeros(0)
    xs = np.concatenate([[CLEAR_BINS[0]], clearance_speeds()]) * body / fps
    return xs, np.concatenate([[0.0], np.asarray(curve, dtype=float)]) * body


def clearance_lift(toe: np.ndarray, free: np.ndarray, floor: float, up: int, body: float, fps: float,
                   clear: float = TOE_CLEAR, curve: np.ndarray | None = None) -> np.ndarray:
    """How much to raise a foot (L,) so that its toe stays out of the floor, and clears it while it
    swings.

    ``toe`` (L, 3) the toe's positions over the new frames, ``free`` (L,) bool the frames where the
    foot is not held, ``floor`` the floor's height for this toe. In a free frame the toe's
    horizontal speed (its shorter step, :func:`slower_step`) asks for ``body`` times
    :func:`clearance_need` (``clear``: ``TOE_CLEAR``, 0 for the ankle of a foot without a toe
    joint; ``curve``: a library's :func:`clearance_curve`, or None) above the floor; a
    held foot's toe asks for the floor itself (a retrieved stance can put it a few centimetres
    under it). The shortfall of a frame's height below that is its
    deficit. With ``r = round(CLEAR_S * fps)`` (at least 1), the free frames' deficits and the
    held frames' each give a lift, the mean over ``[t - r, t + r]`` of the largest deficit within
    ``r`` of each frame: at least the deficit at every frame, rising and falling linearly over
    ``2r`` frames. Near the seams each is faded to 0 on a smoothstep from frame -1 and frame L, so
    A's and B's frames are not moved: over ``CLEAR_FADE_S`` (at least two frames) for the free
    frames' (over ``r + 1`` frames, the toes of the first and last tenth of a gap skated three
    times the truth's on LaFAN1 at 30 fps; the toes' vertical acceleration at the seams stays
    within the real motion's), over ``2r + 1`` for the
    held frames' (a planted leg is often straight, and lifting a straight leg's ankle bends its
    knee by the square root of the lift: over ``r + 1`` frames the knee of a standing leg jumped at
    A's seam). The lift is the larger of the two.
    """
    length = len(toe)
    if length == 0:
        return np.zeros(0)
    flat = np.ones(3)
    flat[up] = 0.0
    speed = slower_step(toe * flat) * fps / body
    need = body * clearance_need(speed, clear, curve)
    deficit = np.maximum(np.where(free, need, 0.0) - (toe[:, up] - floor), 0.0)
    if not deficit.any():
        return np.zeros(length)
    r = max(1, round(CLEAR_S * fps))
    lift = np.zeros(length)
    for frames, fade in ((free, _fade_frames(fps)), (~free, 2.0 * r + 1.0)):
        part = np.where(frames, deficit, 0.0)
        if not part.any():
            continue
        padded = np.concatenate([np.zeros(2 * r), part, np.zeros(2 * r)])
        widest = np.lib.stride_tricks.sliding_window_view(padded, 2 * r + 1).max(axis=-1)  # centred on t - r
        smooth = np.lib.stride_tricks.sliding_window_view(widest, 2 * r + 1).mean(axis=-1)
        edge = np.clip(np.minimum(np.arange(1, length + 1), np.arange(length, 0, -1)) / fade, 0.0, 1.0)
        lift = np.maximum(lift, smooth * edge * edge * (3.0 - 2.0 * edge))
    return lift


def contact_runs(on: np.ndarray) -> list[tuple[int, int]]:
    """Runs ``[start, stop)`` of True in a bool array."""
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def stance_windows(moves, length: int, step: int, least: float) -> np.ndarray:
    """Where each standing foot steps (:func:`lock_feet`): ``(k0, k)`` per leg (n, 2), the step's
    first frame and its frames, or ``(-1, -1)`` for a step in the middle of its run.

    ``moves`` (n,): how far each foot must go from A's spot to B's (NaN for a foot that does
    not stand at both seams); ``length`` the new frames; ``step`` a step's frames; ``least``
    the distance from which a foot counts. Where two feet or more move farther than ``least``,
    the gap is cut into as many equal parts (``r * length // parts`` on), the farthest foot
    first (the lower index on a tie), and each steps in the middle of its part, over ``step``
    frames at most and its whole part at most (one foot lands as the next lifts; a step starts
    and ends in place, :func:`_step`). One foot alone keeps the middle of the gap (all ``-1``),
    and so do all where a part would be shorter than three frames. A frame short of the part at
    each end, two feet moving 21 cm in a 10-frame gap at 30 fps stepped over 3 frames each: the
    toe set off at 10 cm a frame squared.
    """
    moves = np.asarray(moves, dtype=float)
    out = np.full((len(moves), 2), -1, dtype=np.int64)
    legs = sorted((i for i in range(len(moves)) if moves[i] > least), key=lambda i: (-moves[i], i))
    parts = len(legs)
    if parts < 2 or length // parts < 3:
        return out
    for r, leg in enumerate(legs):
        lo, hi = r * length // parts, (r + 1) * length // parts
        k = max(0, min(step, hi - lo))
        out[leg] = (lo + (hi - lo - k) // 2, k)
    return out


def _glides(ankle: np.ndarray, a_spot: np.ndarray, b_spot: np.ndarray, flat: np.ndarray, up: int, top: float,
            off: float) -> bool:
    """Whether the motion's ankle (L, 3) glides from A's spot to B's (up coordinates zeroed): it
    stays under the height ``top`` and within ``off`` of the line between the spots. A leg the
    motion lifts (a kick) or swings wide is not held through the gap."""
    if len(ankle) == 0 or ankle[:, up].max() >= top:
        return False
    d = b_spot - a_spot
    p = ankle * flat - a_spot
    u = np.clip(p @ d / max(float(d @ d), 1e-300), 0.0, 1.0)
    return bool(np.linalg.norm(p - u[:, None] * d, axis=1).max() <= off)


def lock_weights_and_targets(h, horiz, a_on, a_spot, b_on, b_spot, floor, height_tol, speed=None,
                             speed_tol=np.inf, on=None, step=0, lift=0.0, reach=np.inf, window=None, toe=None,
                             toe_seams=None, shuffle=0.0, accel=np.inf, farthest=np.inf, rise=None):
    """Per frame of the new frames: lock weight (L,), horizontal target (L, 3) and lift (L,).

    ``h`` (L,) ankle heights, ``horiz`` (L, 3) ankle positions with the up coordinate zeroed,
    ``a_on``/``b_on`` whether the foot is planted at A's end / B's start and ``a_spot``/``b_spot``
    where (up coordinate zeroed). A frame is on the ground when the ankle is low and, given
    ``speed`` (L,) per frame, slow (a low foot that swings through is not planted). Inside a run
    of ground frames the weight is 1 and the target the run's spot; elsewhere the weight is 0 and
    the target the foot's own position (:func:`swing_offsets` carries the runs' corrections
    through the frames between them). ``on`` (L,) bool, when given, says which frames are planted
    instead (e.g. the contacts of a retrieved real segment). A run that begins at A's end where
    A's foot is not planted (or ends at B's start where B's is not) is not held in its ``step``
    frames at that seam (all of it without a step or where it is shorter than ``step`` + 2):
    held up to the seam, its spot would jump there; let go, its offset passes to the seam's
    through the air.

    A run planted at both A's end and B's start holds A's spot, then steps to B's over the
    ``step`` frames in its middle (at most the run but one frame at each end): the target moves
    with a smoothstep (in place over the step's first and last ``STEP_LAG``, less where that would
    set the foot off faster than ``accel`` per frame squared: :func:`step_lag`) while the foot rises
    by ``lift`` (at most ``rise``, else ``STEP_RISE``, of the step's length beyond ``shuffle``) on a
    squared sine and comes down on B's spot. The lift (L,) is added to the ankle's height. Where
    the two spots lie farther apart than ``farthest``, no step of a standing foot makes it (the
    motion carries the foot there: a body gliding over a standing segment), and the run is not
    held.
    ``window`` ``(k0, k)``, when given: that step over frames ``k0 .. k0 + k - 1`` of the run
    instead (:func:`stance_windows`).

    ``toe_seams`` ``(a_toe_on, a_toe_spot, b_toe_on, b_toe_spot, low, most[, catch[, after_run]])``,
    with ``toe``: a toe planted at a seam (the heel may be up) stays on its spot while ``low`` (L,)
    says the new frames keep it low, at most ``most`` frames, and no longer than lets its offset
    pass on at ``catch`` per frame; after a run of at most ``after_run`` frames from the seam, where
    the run leaves it (:func:`_hold_seam_toes`). ``shuffle``: a step lifts the foot by ``rise``
    (``STEP_RISE``; the lock: :func:`step_rise` of its gap) of its way beyond this (:func:`_step`).

    ``toe`` (L, 3), when given: per frame the toe's horizontal place relative to the ankle. A
    held foot then turns about its toe, not its ankle: the target moves back by how far the toe
    turned about the ankle since the run's reference frame (its spot's: the run's first frame
    for A's spot, its last for B's, its middle for its own; across a step, from the first
    spot's to the last's), so that the toe stays where it was while the foot rolls or turns
    over it. Held by the ankle, the toe slid as the heel rose or the foot turned.

    A run held on one seam's spot only steps too where that spot lies farther than ``reach``
    from where the motion puts the foot at the run's other end (two real segments blended with
    their stances apart, a seam's offset): a run ending at B's start holds the foot where it
    lands moved ``reach`` toward B's spot, then steps onto B's spot; a run starting at A's end
    holds A's spot, then steps to where the foot lifts off moved ``reach`` back toward A's spot
    (the lock holds a foot that far from the motion's without dragging it). Held on the one
    spot, such a foot would be dragged there (the lock moves a foot by at most about
    ``MAX_DRIFT`` of a leg; :func:`lock_feet`). It needs a step of at least one frame and one
    more frame at each end; a shorter run, or no step, keeps the one spot.
    """
    length = len(h)
    if on is None:
        on = h < floor + height_tol
        if speed is not None:
            on &= speed < speed_tol
    else:
        on = np.array(on, dtype=bool)
    # A run at a seam where that clip's foot is not planted would jump there (to B's spot from
    # A's first new frame): its ``step`` frames at that seam are not held (the foot goes to the
    # seam's through the air), nor the whole run where fewer than two frames would be left.
    runs = contact_runs(on)
    if runs and runs[0][0] == 0 and not a_on:
        on[: step if 0 < step <= runs[0][1] - 2 else runs[0][1]] = False
    runs = contact_runs(on)
    if runs and runs[-1][1] == length and not b_on:
        on[length - step if 0 < step <= length - runs[-1][0] - 2 else runs[-1][0]:] = False
    weight = np.zeros(length)
    raised = np.zeros(length)
    target = horiz.copy()
    for start, stop in contact_runs(on):
        from_a = start == 0 and a_on
        to_b = stop == length and b_on
        n = stop - start
        spot = np.empty((n, 3))
        ref = np.zeros(n)  # where the spot is between the run's first spot and its last, 0 to 1
        if from_a and to_b and np.linalg.norm(b_spot - a_spot) > farthest:
            continue  # no step makes it: the motion's own foot
        if from_a and to_b:  # planted all through: A's spot, a step in the middle of the run, B's spot
            ref = _step(spot, raised[start:stop], a_spot, b_spot, step, lift, window, shuffle, accel, rise)
        elif from_a and 0 < step <= n - 2 and np.linalg.norm(horiz[stop - 1] - a_spot) > reach:
            ref = _step(spot, raised[start:stop], a_spot, _toward(horiz[stop - 1], a_spot, reach), step, lift,
                        None, shuffle, accel, rise)
        elif from_a:
            spot[:] = a_spot
        elif to_b and 0 < step <= n - 2 and np.linalg.norm(b_spot - horiz[start]) > reach:
            ref = _step(spot, raised[start:stop], _toward(horiz[start], b_spot, reach), b_spot, step, lift,
                        None, shuffle, accel, rise)
        elif to_b:
            spot[:] = b_spot
            ref[:] = 1.0
        else:
            spot[:] = horiz[(start + stop - 1) // 2]
        weight[start:stop] = 1.0
        target[start:stop] = spot
        if toe is not None:  # the toe held where it was at the spot's frame: a seam's, or the run's middle
            run_toe = toe[start:stop]
            first, last = (run_toe[0], run_toe[-1]) if from_a or to_b else (run_toe[(n - 1) // 2],) * 2
            target[start:stop] -= run_toe - (first + ref[:, None] * (last - first))
    if toe_seams is not None and toe is not None:
        _hold_seam_toes(weight, target, toe, *toe_seams, horiz=horiz)
    return weight, target, raised


def _hold_seam_toes(weight, target, toe, a_toe_on, a_toe_spot, b_toe_on, b_toe_spot, low, most, catch=np.inf,
                    after_run=0, horiz=None):
    """A toe planted at a seam stays on its spot while the new frames keep it low, in place: from
    A's end (``a_toe_on``, its spot ``a_toe_spot``), when its first new frame is not held, the frames
    ``low`` (L,) up to the first that is not, at most ``most`` of them and ``(L - SEAM_TOE_GAP) // 2``
    (so that two seams' holds leave that many frames between them), hold the ankle where the toe
    stays on the spot (``toe`` (L, 3) the toe's horizontal place about the ankle); at least
    ``SEAM_TOE_GAP`` frames are left free before a frame held already (held through a short gap,
    a toe jumped to B's spot at B's seam). Where a run holds the foot from the seam for at most
    ``after_run`` frames, the toe is held the same way after the run, where the run leaves it
    (``most`` more frames at most): the foot lifts off its toe, as it does when the heel is up at
    the seam. Let go with the run, the toe swept away low over the floor at once, and the lift
    that clears it, faded in over the seam's ``CLEAR_FADE_S``, bent a straight knee in a frame or
    two (bow into dance: the knee 5.6 cm per frame squared at A's seam, the bow at most 0.01).
    The same back from B's start, after A's. With ``horiz`` (L, 3), the ankle's place: the hold
    ends early enough for its offset to pass to the next held frame's (or to nothing at the other
    seam) at most ``catch`` per frame (length unit), so that the foot is not thrown across in the
    few frames between two spots."""
    length = len(weight)
    forward = np.arange(length)
    for on, spot, frames in ((a_toe_on, a_toe_spot, forward), (b_toe_on, b_toe_spot, forward[::-1])):
        if not on or length == 0:
            continue
        n0 = 0  # the frames a run holds from the seam: the toe stays where the run leaves it
        while n0 < length and weight[frames[n0]] > 0:
            n0 += 1
        if n0 == length or n0 > after_run:
            continue
        if n0 > 0:
            spot = target[frames[n0 - 1]] + toe[frames[n0 - 1]]
        n = n0
        while n < min(n0 + most, (length - SEAM_TOE_GAP) // 2) and low[frames[n]] and weight[frames[n]] == 0:
            n += 1
        held = np.flatnonzero(weight[frames[n0:]] > 0) + n0
        after = length if len(held) == 0 else int(held[0])  # the next held frame; `length`: the other seam
        n = min(n, max(after - SEAM_TOE_GAP, n0))
        if horiz is not None:
            goal = np.zeros(3) if after == length else target[frames[after]] - horiz[frames[after]]
            while n > n0 and np.linalg.norm(spot - toe[frames[n - 1]] - horiz[frames[n - 1]] - goal) > catch * (
                    after - n + 1):
                n -= 1
        hold = frames[n0:n]
        weight[hold] = 1.0
        target[hold] = spot - toe[hold]


def _toward(x: np.ndarray, y: np.ndarray, reach: float) -> np.ndarray:
    """``x`` moved ``reach`` toward ``y`` (which lies farther)."""
    return x + (y - x) * (reach / float(np.linalg.norm(y - x)))


def step_lag(k: int, way: float, accel: float) -> float:
    """The share of a ``k``-frame step's frames at each end where the foot rises or comes down in
    place: ``STEP_LAG``, less where the smoothstep between would accelerate the foot faster than
    ``accel`` (per frame squared) over ``way``: it moves over ``(1 - 2 lag) (k + 1)`` frames,
    whose peak acceleration is ``6 way`` over their square. A 10-frame gap at 30 fps with both
    feet to move 21 cm stepped each over 5 frames, 3 of them moving: the toe set off at 8.5 cm
    a frame squared (a walking ankle's bound, ``PASS_ACCEL``, 3.6)."""
    if k <= 0 or way <= 0.0 or not np.isfinite(accel):
        return STEP_LAG
    return float(min(max(0.5 * (1.0 - np.sqrt(6.0 * way / accel) / (k + 1.0)), 0.0), STEP_LAG))


def _step(spot: np.ndarray, raised: np.ndarray, first: np.ndarray, last: np.ndarray, step: int, lift: float,
          window=None, shuffle: float = 0.0, accel: float = np.inf, rise: float | None = None) -> np.ndarray:
    """A run's spots (n, 3) and lift (n,), in place: ``first``, a step over the ``step`` frames in
    the run's middle (at most the run but one frame at each end), ``last``. A run of 1 or 2
    frames: ``first`` (if 2), then ``last``. ``window`` ``(k0, k)``: the step over frames ``k0 ..
    k0 + k - 1`` instead. The foot travels on a smoothstep between the step's first and last
    ``STEP_LAG`` (less where the step is too quick for it: :func:`step_lag`, ``accel``) and
    rises on a squared sine over the whole step (no vertical speed at either end; on a half sine
    it rose from rest in one frame) to ``lift`` at most and ``rise`` (``STEP_RISE``; the lock:
    :func:`step_rise` of its gap) of the way beyond ``shuffle`` (``STAND_STEP``: a foot shifted a
    few centimetres slides or pivots on the floor; see :func:`step_lift`). Returns how far the
    step has gone at each frame (n,), 0 to 1."""
    n = len(spot)
    if window is None:
        k = max(0, min(step, n - 2))
        k0 = (n - k) // 2
    else:
        k0, k = int(window[0]), int(window[1])
    share = np.zeros(n)
    share[k0 + k:] = 1.0
    spot[:k0], spot[k0 + k:] = first, last
    if k > 0:
        u = np.arange(1, k + 1) / (k + 1.0)
        lag = step_lag(k, float(np.linalg.norm(last - first)), accel)
        v = np.clip((u - lag) / (1.0 - 2.0 * lag), 0.0, 1.0)
        share[k0: k0 + k] = v * v * (3 - 2 * v)
        spot[k0: k0 + k] = first + share[k0: k0 + k, None] * (last - first)
        raised[k0: k0 + k] = step_lift(k, float(np.linalg.norm(last - first)), lift, shuffle, accel, rise)
    return share


def swing_offsets(offset: np.ndarray, runs, carry: int | None = None) -> np.ndarray:
    """Fill ``offset`` (L, k) between the ``runs`` (``[start, stop)``, in order) in place; returns it.

    ``offset`` holds in the runs' frames what they need (a planted foot's correction). Each stretch
    of frames between two runs goes from the value and rate (the difference of its last two
    frames; 0 for a one-frame run) at the end of the run before to those at the start of the run
    after; before the first run it starts from 0 at rest on frame -1 (A's last frame), after the
    last it comes to rest at 0 on frame L (B's first). Without runs the offset is 0. The curve has
    a continuous value and rate everywhere, A's and B's frames included: a smoothstep from value
    to value over the stretch, plus each end's rate carried over ``carry`` frames at most (the
    cubic Hermite's own terms for it, ``u (1 - u)^2`` and ``u^2 (u - 1)``, over that many frames,
    then nothing). ``carry`` None or at least the stretch: the cubic Hermite curve itself.

    A rate carried over a long stretch bulged the offset: a foot held at A's seam while the motion
    under it rose into a scissor kick left the run at 1.8 cm a frame, which the Hermite over 38
    frames (LaFAN1 at 60 fps) carried 13 cm out from where the motion put the foot, at the top of
    the kick, where the leg was folded tight: the knee swung 38 cm up through the ankle and back.
    """
    length = len(offset)
    zero = np.zeros(offset.shape[1:])

    def rate(start, stop, at_start):
        if stop - start < 2:
            return zero
        return offset[start + 1] - offset[start] if at_start else offset[stop - 1] - offset[stop - 2]

    if not runs:
        offset[:] = 0.0
        return offset
    anchors = [(-1, zero, zero)]  # (frame, value, rate) at each side of a free stretch
    for start, stop in runs:
        anchors += [(start, offset[start], rate(start, stop, True)),
                    (stop - 1, offset[stop - 1], rate(start, stop, False))]
    anchors.append((length, zero, zero))
    for (p, vp, rp), (q, vq, rq) in zip(anchors[0::2], anchors[1::2], strict=True):
        if q - p < 2:
            continue
        span = q - p
        window = float(span if carry is None else max(min(carry, span), 1))
        s = np.arange(1, span)[:, None].astype(float)
        u, a, b = s / span, np.minimum(s / window, 1.0), np.maximum(1.0 - (span - s) / window, 0.0)
        offset[p + 1: q] = (vp + (3 * u**2 - 2 * u**3) * (vq - vp) + window * a * (1 - a) ** 2 * rp
                            + window * b**2 * (b - 1) * rq)
    return offset


def pass_accel(way: np.ndarray, rate_p: np.ndarray, rate_q: np.ndarray, span: int,
               carry: int | None = None) -> float:
    """The peak acceleration (per frame squared) of the curve :func:`swing_offsets` lays over
    ``span`` frames from a value at rate ``rate_p`` (per frame) to a value ``way`` further at
    rate ``rate_q``, each rate carried over ``carry`` frames at most (None: the whole span, the
    cubic Hermite: ``|6 way - span (4 rate_p + 2 rate_q)| / span^2`` at its start, ``|6 way -
    span (2 rate_p + 4 rate_q)| / span^2`` at its end). The curve's second derivative is linear
    between the ends and the windows' edges: the peak is at one of them, on one side or the other.
    With both rates 0, a smoothstep's ``6 |way| / span^2``.

    A foot held on its spot while the motion under it moves on leaves the run with the offset
    changing at the motion's speed; the curve that takes the offset on from there starts the foot
    from rest, and the motion's speed must be reached within the stretch too: LaFAN1 at 60 fps, a
    splice's blend moving a held foot 3.5 cm a frame, the foot set off at 2.2 cm a frame squared
    (the lock's walking bound 0.9) where the offsets' gap alone (19 cm over 10 frames) passed.
    """
    way = np.asarray(way, dtype=float)
    window = float(span if carry is None else max(min(carry, span), 1))

    def second(s, side):  # at s, the windows' terms taken as just after (side 1) or before (-1)
        out = way * (6.0 - 12.0 * s / span) / span**2
        if s + 0.5 * side < window:
            out = out + rate_p * (6.0 * s / window - 4.0) / window
        if s + 0.5 * side > span - window:
            out = out + rate_q * (6.0 * (1.0 - (span - s) / window) - 2.0) / window
        return float(np.linalg.norm(out))

    return max(second(s, side) for s, side in ((0, 1), (span, -1), (window, -1), (window, 1),
                                               (span - window, -1), (span - window, 1))
               if 0 < s + 0.5 * side < span)


def pace_passes(held: np.ndarray, weight: np.ndarray, offset: np.ndarray, raised: np.ndarray, h: np.ndarray,
                pace: float, lift: float, shuffle: float, accel: float = np.inf, least: int = 1,
                carry: int | None = None, foot: np.ndarray | None = None, rise: float | None = None) -> None:
    """Widen the free stretches between held runs whose offsets differ by more than ``pace`` (per
    frame) and ``accel`` (per frame squared) allow; in place, before :func:`swing_offsets` carries
    the offsets through them.

    ``held`` (L,) bool, ``weight`` (L,), ``offset`` (L, k) (the runs' corrections), ``raised`` (L,)
    the lift, ``h`` (L,) the ankle's height in the motion. A stretch from a run's last held frame
    ``p`` to the next run's first ``q`` (A's frame -1 or B's frame L, offset 0, at the ends)
    passes ``d = |offset[q] - offset[p]|`` over ``q - p`` frames; where that is under ``d /
    pace`` or, with a free frame between, the curve :func:`swing_offsets` carries through it
    (each run's rate over ``carry`` frames at most) accelerates faster than ``accel``
    (:func:`pass_accel`; the runs' rates included: a foot held while the motion under it moves on
    sets off from rest to the motion's pace within the bound too), the runs let go of their frames next to the
    stretch, the longer run first, each keeping one frame; the stretches are checked again until
    none widens (a run shortened by the stretch after it has another rate at the one before,
    none with one frame left). Of the runs left shorter than
    ``least`` frames (and than they were), the shortest as it came is let go entirely, and the
    widening starts again from the runs as they came without it, its two stretches one: its
    neighbours get back the frames they gave up for it. A splice of two real segments, or a
    seam's spot held against a motion that placed the foot elsewhere, can leave one free frame
    between two held spots 46 cm apart: the foot jumped 23 cm a frame twice, where a walking
    swing moves it about 12; passed at that pace over the fewest frames, it still set off at two
    to five times the acceleration of a walking ankle (46 cm in six frames at 30 fps, 20 cm in
    five at 60), and a run shortened to a frame or two put the foot down between two such
    passes, a hop. Every stretch that changed lifts the foot as a step of the lock does
    (:func:`step_lift`: ``lift`` at most, ``rise`` (else ``STEP_RISE``) of the way beyond
    ``shuffle``, on a squared sine within ``accel``) less what the motion lifts it already; the
    way is the foot's own between the two held frames, ``foot`` (L + 2, k: the motion's foot, as
    ``offset`` lies, in A's last
    frame, the new ones and B's first) with the offsets, where given and the stretch no longer
    than ``carry`` frames (a longer one follows
    the motion's own foot after those: lifted over the whole of it, a foot the motion glided
    along the floor for 0.67 s rose 7 cm into one long step while the other was up, a float),
    else the offsets' gap. A foot let go sooner because the motion under it moved on travels
    that motion's way too: lifted by the gap alone it slid low along the floor (between bandai1
    clips, ``bench/transition_feet.py``: 2.29 / 1.83 / 1.73 cm/s at 15 / 30 / 45 frames; by its
    own way 2.09 / 1.72 / 1.63). At a seam the way starts at A's foot (ends at B's).
    """
    length = len(held)
    if length == 0 or pace <= 0:
        return
    zero = np.zeros(offset.shape[1:])

    def gap(p, q):
        return float(np.linalg.norm((offset[q] if q < length else zero) - (offset[p] if p >= 0 else zero)))

    def too_quick(p, q, lo, hi):
        # The pass from p (its run from lo) to q (its run to hi) at the pace, and (a free frame
        # between) the carried curve's peak acceleration, the runs' rates included (pass_accel).
        d = gap(p, q)
        if q - p < d / pace:
            return True
        if q - p < 2:
            return False
        rp = offset[p] - offset[p - 1] if p - 1 >= lo else zero
        rq = offset[q + 1] - offset[q] if q + 1 < hi else zero
        return pass_accel((offset[q] if q < length else zero) - (offset[p] if p >= 0 else zero), rp, rq,
                          q - p, carry) > accel

    def stretches(runs):
        ends = [-1] + [stop - 1 for _, stop, *_ in runs]
        return list(zip(ends, [start for start, *_ in runs] + [length], strict=True))

    original = [(int(start), int(stop)) for start, stop in contact_runs(held)]
    first = set(stretches(original))
    given = weight.copy()
    dropped: set[int] = set()
    while True:
        # From the runs as they came, less those let go whole: the frames a dropped run's
        # neighbours gave up for it are theirs again.
        runs = []
        for k, (start, stop) in enumerate(original):
            keep = k not in dropped
            held[start: stop] = keep
            weight[start: stop] = given[start: stop] if keep else 0.0
            if keep:
                runs.append([start, stop, k])
        # Until no stretch widens: a run the next stretch shortens changes its rate at the
        # stretch before (down to none, one frame left), which is checked again.
        widened = True
        while widened:
            widened = False
            for i in range(len(runs) + 1):
                p = runs[i - 1][1] - 1 if i > 0 else -1
                q = runs[i][0] if i < len(runs) else length
                while True:
                    # Next to a seam with no free frame between, the correction is not carried
                    # through frames (the foot is held on both sides): the pace alone, as for a jump.
                    if not too_quick(p, q, runs[i - 1][0] if i > 0 else 0, runs[i][1] if i < len(runs) else length):
                        break
                    left = p - runs[i - 1][0] if i > 0 else 0  # frames the run before can let go
                    right = runs[i][1] - 1 - q if i < len(runs) else 0
                    if left <= 0 and right <= 0:
                        break
                    widened = True
                    if left >= right:
                        held[p], weight[p] = False, 0.0
                        p -= 1
                    else:
                        held[q], weight[q] = False, 0.0
                        q += 1
                if i > 0:
                    runs[i - 1][1] = p + 1
                if i < len(runs):
                    runs[i][0] = q
        short = [(original[k][1] - original[k][0], k) for start, stop, k in runs
                 if stop - start < min(least, original[k][1] - original[k][0])]
        if not short:
            break
        dropped.add(min(short)[1])  # the shortest as it came: a long run shrank for its sake
    for p, q in stretches(runs):
        if (p, q) in first:
            continue
        base = min(h[p] if p >= 0 else h[0], h[q] if q < length else h[-1])
        free = slice(p + 1, q)
        way = gap(p, q)
        if foot is not None and q - p <= (length + 1 if carry is None else carry):  # the foot's own way:
            # the motion's with the offsets' (a longer stretch is the motion's own after carry frames)
            way = float(np.linalg.norm(foot[q + 1] + (offset[q] if q < length else zero)
                                       - foot[p + 1] - (offset[p] if p >= 0 else zero)))
        raised[free] = np.maximum(raised[free], step_lift(q - p - 1, way, lift, shuffle, accel, rise)
                                  - np.maximum(h[free] - base, 0.0))


def step_lift(k: int, way: float, lift: float, shuffle: float, accel: float = np.inf,
              rise: float | None = None) -> np.ndarray:
    """The lift (k,) of a step over ``k`` frames that moves a foot ``way``: a squared sine
    (no vertical speed at either end) up to ``lift`` at most and ``rise`` (``STEP_RISE``; the lock
    gives :func:`step_rise` of its gap) of the way beyond ``shuffle`` (a shorter shift slides or
    pivots on the floor), and no higher than lets it
    accelerate within ``accel`` per frame squared (a squared sine over ``k + 1`` frames peaks at
    ``2 pi^2 / (k + 1)^2`` times its height); :func:`_step`'s and the steps :func:`pace_passes`
    makes.

    The share is what real feet do. Where a foot is planted at both ends of a gap (within
    ``CONTACT_HEIGHT`` of its floor, slower than ``CONTACT_SPEED``) and has moved between them,
    the ankle's highest rise in the gap over the higher of its two ends, in leg lengths, medians
    over every such window of bandai1 (every second clip) and of LaFAN1's segments of subjects
    1-4 (every third), by the way moved:

    | way (leg lengths) | 0.5 s gaps: bandai1 / LaFAN1 | 1 s gaps | 0.17 s and 0.3 s gaps |
    |---|---|---|---|
    | 0.05-0.1 | 0.000 / 0.002 | 0.011 / 0.005 | 0.000 |
    | 0.1-0.2 | 0.013 / 0.019 | 0.016 / 0.029 | 0.000-0.012 |
    | 0.2-0.4 | 0.012 / 0.044 | 0.029 / 0.050 | 0.006-0.017 |
    | 0.4-1.0 | 0.052 / 0.059 | 0.083 / 0.101 | 0.017-0.042 |

    A foot shifted a few centimetres slides or pivots; one moved half a leg or more steps. A
    fifth of the way beyond ``shuffle`` follows the medians of 0.5-1 s (0.02 at 0.15 leg lengths,
    0.05 at 0.3, ``lift`` from 0.55); on gaps under ``STEP_RISE_S`` the lock asks for less
    (:func:`step_rise`, its ``rise``), and the acceleration bound lowers it too. The whole
    way (up to ``lift``) had been kept before for the skate of transitions between standing clips
    (a foot shifted 6.4 cm between two of Motiondataset-2's clips slid over the floor), but it lifted
    feet three to ten times higher than real feet rise over the same way, and in-betweening paid for
    it in L2P: LaFAN1's segments at 60 fps, 0.17 / 0.5 / 1 s, 0.315 / 1.191 / 2.528 -> 0.282 / 1.187 /
    2.518 with a quarter of the way; bandai1's held-out contents 0.330 / 1.191 / 1.797 -> 0.325 /
    1.190 / 1.795 (every share from the whole way to none lowered L2P a little more, none lowest; none
    would glide every foot that steps). With the fifth kept: LaFAN1 at 60 fps, 0.5 / 1 / 1.5 s,
    1.186 / 2.528 / 3.856 -> 1.182 / 2.516 / 3.843; the bench's held-out contents at 15 / 30 / 45
    frames 1.170 / 1.788 / 2.089 -> 1.168 / 1.786 / 2.087, held-out styles 0.611 / 1.005 / 1.200 ->
    0.609 / 1.000 / 1.198. The price is paid between clips, where B's stance is not
    A's: on 100 seeded transitions between bandai1's clips (every second clip, B placed to continue
    A; the default with the lock) the skate at 10 / 20 / 30 frames went 2.71 / 1.68 / 1.38 -> 4.26 /
    2.42 / 1.90 cm/s with a fifth of the way, the clips' own windows 2.66 / 2.24 / 2.40, SLERP's 25 /
    21 / 18."""
    u = np.arange(1, k + 1) / (k + 1.0)
    rise = STEP_RISE if rise is None else rise
    high = min(lift, rise * max(way - shuffle, 0.0), accel * (k + 1.0) ** 2 / (2.0 * np.pi**2))
    return high * np.sin(np.pi * u) ** 2


def step_rise(length: int, fps: float) -> float:
    """The share of its way (beyond ``STAND_STEP``) by which a step in a gap of ``length`` new
    frames lifts the foot: ``STEP_RISE``, times the gap's share of ``STEP_RISE_S`` where it is
    shorter (from A's last frame to B's first, ``(length + 1) / fps`` seconds): 0.093 for 6 new
    frames at 30 fps. No frames or an unknown rate: ``STEP_RISE``.

    Real feet hardly rise over short gaps (the table of :func:`step_lift`: over 0.17-0.3 s, a
    foot planted at both ends rose about a twentieth of its way, at 0.5 s a tenth to a fifth, at
    1 s about a fifth), and a step the lock lifted by a fifth there cost in-betweening its L2P:
    the knees and feet, held higher than the truth's, carried the lock's whole cost in the
    vertical (L2P divides a height by its small spread). With this, L2P of the default at 0.1 /
    0.2 / 0.3 s (seconds scaled by
    the clips' rate; the bench's protocol, 10 context frames each side): bandai1's held-out
    styles 0.1053 / 0.2759 / 0.4216 -> 0.1022 / 0.2547 / 0.4191, held-out contents 0.1587 / 0.3994
    / 0.6474 -> 0.1555 / 0.3726 / 0.6424, LaFAN1's subject 5 at 60 fps 0.1220 / 0.3615 / 0.6155 ->
    0.1171 / 0.3352 / 0.6114; CMU 01_01 at 120 fps within 0.2%; from 0.5 s the same. The skate
    against the truth at 0.2 s: 1.79 -> 1.84 cm/s (held-out styles; the truth's about 3.7).
    Scaled over a whole second instead (a tenth at 0.5 s, as the 0.5 s medians), L2P fell
    further (0.2444 / 0.3644 / 0.3240 at 0.2 s) but transitions between two of bandai1's clips,
    whose stances differ more than a gap's, slid their feet at 0.5 s: the skate of 100 seeded
    transitions of 15 frames 2.79 -> 4.52 cm/s (the clips' own windows 2.42); with 0.5 s, at 10
    frames 4.27 -> 5.25 (1.88), at 5 frames 19.1 -> 21.3 (2.56: a foot must reach B's stance in
    a sixth of a second), from 15 frames the same. So at 0.3 s the lock still lifts twice as
    high as real feet rise (0.12 of the way), and at 0.5 s as high as the highest medians: a
    compromise with the feet of transitions between clips, not the truth's medians."""
    if length <= 0 or not np.isfinite(fps) or fps <= 0.0:
        return STEP_RISE
    return STEP_RISE * min(1.0, (length + 1.0) / (fps * STEP_RISE_S))


def _planted(seam, next_to_it, floor: float, up: int, height_tol: float, speed_tol: float) -> bool:
    """Whether a foot joint at a seam frame (3,) is planted: within ``height_tol`` of ``floor`` and
    moved less than ``speed_tol`` horizontally from the frame next to it (3,) (A's one before, B's
    one after)."""
    step = seam - next_to_it
    step[up] = 0.0
    return bool(seam[up] < floor + height_tol and np.linalg.norm(step) < speed_tol)


def _fade_frames(fps: float) -> float:
    """The frames over which a swinging toe's lift fades in at each seam: ``CLEAR_FADE_S``, at
    least two."""
    return float(max(2, round(CLEAR_FADE_S * fps)))


def lock_feet(sk: Skeleton, chains, rots, positions, gpos_fn, up: int, a_feet, b_feet, fps: float,
              contacts=None, body: float | None = None, toe_floor=None, toes=None, seam_floors=None,
              clearance: np.ndarray | None = None, a_toes=None, b_toes=None) -> np.ndarray:
    """Pull planted feet onto their spots in the new frames; modifies ``rots`` in place.

    ``rots``/``positions`` (L, J, 4)/(L, J, 3) are the new frames' local rotations and
    translations; ``gpos_fn(rots)`` gives their global rotations and positions (L, J, 4/3).
    ``a_feet``/``b_feet`` (2, n_legs, 3) are the ankle positions in A's last two frames and
    B's first two (B as aligned), for the planted test. ``contacts`` (L, n_legs) bool, when
    given, are the planted frames (otherwise they are detected from height and speed). ``body``:
    :func:`leg_length` of the skeleton, and ``toes`` (n_legs,): :func:`leg_toes`, when the caller
    keeps them. ``toe_floor``, when given: the lowest height of the toes in the context (the
    engine: over A's last ``FLOOR_S`` seconds and B's first); a toe under it is lifted out, held
    or not. Without it, the lowest toe of a held foot in the new frames, or with none held, the
    lowest toe in the new frames. ``seam_floors``, when given: the lowest ankle of A's last
    ``FLOOR_S`` seconds and of B's first (B's as aligned), the floors that say whether a foot is
    planted at each seam; without them, a leg's lowest ankle in its four seam frames and the new
    frames (which a blend or an interpolation can take under the floor B stands on: B's foot,
    planted, was then taken for lifted, and its run was not held). ``clearance``: the motion
    library's :func:`clearance_curve`, the least height of its swinging toes by speed, which
    raises the swinging toes' clearance where it lies above ``TOE_CLEAR``'s (None: that alone).
    ``a_toes``/``b_toes`` (2, n_legs, 3), when given: the toes in A's last two frames and B's first
    two (B as aligned; a leg without a toe joint: its ankle). A toe planted at a seam (within
    ``CONTACT_HEIGHT`` of the toes' floor, slower than ``CONTACT_SPEED``), whose foot the first new
    frame (the last, at B) does not hold, stays on its spot while the new frames keep it that low,
    at most ``SEAM_TOE_S`` and half the gap, and no longer than lets its offset pass on to the next
    held frame's at ``SEAM_TOE_CATCH``: a heel rises from a planted toe, and a retrieved segment's
    toe, in another phase of its step, slid off it at once. So does a toe whose foot a run holds
    there for no longer than the lift's fade at the seam (``CLEAR_FADE_S``), after the run.
    Without ``toe_floor``, that test's floor is the leg's lowest of its own four seam toes (a toe
    held still in the air then counts as planted: the engine always gives the context's floor).

    Returns the lock weights (L, n_legs): 1 where a foot is held on its spot, the fraction of the
    way to it where the spot is far from the foot (``MAX_DRIFT``), 0 in the air (where the runs'
    corrections are carried smoothly: :func:`swing_offsets`).
    """
    weights = np.zeros((len(rots), len(chains)))
    if not chains or len(rots) == 0:
        return weights
    body = leg_length(sk, chains) if body is None else body
    toes = leg_toes(sk, chains) if toes is None else np.asarray(toes, dtype=np.int64)
    grot, gpos = gpos_fn(rots)
    toe_floor = np.inf if toe_floor is None else float(toe_floor)
    height_tol = CONTACT_HEIGHT * body
    speed_tol = CONTACT_SPEED * body / fps  # per frame
    a_floor, b_floor = (np.nan, np.nan) if seam_floors is None else (float(seam_floors[0]), float(seam_floors[1]))
    passes = (PASS_SPEED * body / fps, PASS_ACCEL * body / fps**2, max(1, round(PASS_LEAST_S * fps)),
              max(1, round(CARRY_S * fps)))  # pace_passes' and swing_offsets'
    rise = step_rise(len(rots), fps)
    jit = _compiled()
    if jit is not None:  # the same steps, compiled: one call for every leg and frame
        legs = np.array(chains, dtype=np.int64).reshape(-1, 3)
        # Contiguous arrays always: another memory layout makes the kernel compile (or load) a
        # second version on that call, a hitch of 10-40 ms.
        planted = (np.zeros((0, len(chains)), dtype=bool) if contacts is None
                   else np.ascontiguousarray(contacts, dtype=bool))
        seam_toes = ((np.zeros((0, len(chains), 3)),) * 2 if a_toes is None or b_toes is None
                     else (np.ascontiguousarray(a_toes, dtype=float), np.ascontiguousarray(b_toes, dtype=float)))
        jit.lock_legs(sk.parents, legs, rots, grot, gpos, up, np.ascontiguousarray(a_feet, dtype=float),
                      np.ascontiguousarray(b_feet, dtype=float), body, height_tol, speed_tol, planted,
                      MAX_DRIFT[0], MAX_DRIFT[1], IK_EPS, SOFT_REACH, KNEE_HINGE, round(STEP_S * fps),
                      STEP_LIFT * body, STEP_LAG, toes, toe_floor, TOE_CLEAR * body, CLEAR_SPEED[0] * body / fps,
                      CLEAR_SPEED[1] * body / fps, *_clearance_table(clearance, body, fps),
                      max(1, round(CLEAR_S * fps)), _fade_frames(fps), a_floor, b_floor, STAND_STEP * body,
                      rise, STEP_MOST * body,
                      *seam_toes, round(SEAM_TOE_S * fps), SEAM_TOE_GAP, SEAM_TOE_CATCH * body / fps,
                      *passes, HINGE_SURE, KNEE_THROUGH, KNEE_ACCEL / fps**2, rest.REST_PASSES, rest.REST_PLAIN,
                      rest.REST_RELAX, rest.REST_EXACT, weights)
        return weights
    flat = np.ones(3)
    flat[up] = 0.0
    length, step = len(rots), round(STEP_S * fps)
    seams = []  # per leg: its floor, whether it is planted at A's end and at B's start
    moves = np.full(len(chains), np.nan)  # legs held all through, planted at both seams: how far each must go
    for leg, (thigh, shin, ankle) in enumerate(chains):
        context_h = np.concatenate([a_feet[:, leg, up], b_feet[:, leg, up]])
        floor = min(context_h.min(), gpos[:, ankle, up].min())
        a_on = _planted(a_feet[1, leg], a_feet[0, leg], floor if np.isnan(a_floor) else a_floor, up, height_tol,
                        speed_tol)
        b_on = _planted(b_feet[0, leg], b_feet[1, leg], floor if np.isnan(b_floor) else b_floor, up, height_tol,
                        speed_tol)
        seams.append((floor, a_on, b_on))
        move = np.linalg.norm((b_feet[0, leg] - a_feet[1, leg]) * flat)
        if not (a_on and b_on and move <= MAX_DRIFT[1] * body):  # one step's way at most
            continue
        if (contacts[:, leg].all() if contacts is not None else  # held all through by the segment
                _glides(gpos[:, ankle], a_feet[1, leg] * flat, b_feet[0, leg] * flat, flat, up,
                        floor + STEP_LIFT * body, MAX_DRIFT[0] * body)):
            moves[leg] = move
    windows = stance_windows(moves, length, step, STAND_STEP * body)
    locks = []  # per leg: the offsets, lifts and held frames; the IK once the toes' floor is known
    for leg, (thigh, shin, ankle) in enumerate(chains):
        floor, a_on, b_on = seams[leg]
        h = gpos[:, ankle, up]
        horiz = gpos[:, ankle] * flat
        speed = np.linalg.norm(np.diff(np.concatenate([a_feet[1:, leg] * flat, horiz]), axis=0), axis=-1)
        on = None if contacts is None else contacts[:, leg]
        toe_seams = None  # the toe planted at each seam (low and slow), its spot, the new frames' low toes
        if a_toes is not None and b_toes is not None:
            tf = toe_floor if toe_floor != np.inf else min(a_toes[:, leg, up].min(), b_toes[:, leg, up].min())
            a_t = _planted(a_toes[1, leg], a_toes[0, leg], tf, up, height_tol, speed_tol)
            b_t = _planted(b_toes[0, leg], b_toes[1, leg], tf, up, height_tol, speed_tol)
            toe_seams = (a_t, a_toes[1, leg] * flat, b_t, b_toes[0, leg] * flat,
                         gpos[:, toes[leg], up] < tf + height_tol, round(SEAM_TOE_S * fps),
                         SEAM_TOE_CATCH * body / fps, int(_fade_frames(fps)))
        if not np.isnan(moves[leg]):  # interpolated and planted at both seams: held through, one step
            on = np.ones(length, dtype=bool)
        weight, target, raised = lock_weights_and_targets(h, horiz, a_on, a_feet[1, leg] * flat, b_on,
                                                          b_feet[0, leg] * flat, floor, height_tol, speed, speed_tol,
                                                          on, step, STEP_LIFT * body, MAX_DRIFT[0] * body,
                                                          None if windows[leg, 0] < 0 else windows[leg],
                                                          (gpos[:, toes[leg]] - gpos[:, ankle]) * flat, toe_seams,
                                                          STAND_STEP * body, passes[1], STEP_MOST * body, rise)
        # The runs' offsets, softly limited where the spot is far from the foot; carried through
        # the frames between the runs.
        offset = target - horiz
        far = np.linalg.norm(offset, axis=-1) / body
        held = weight > 0
        scale = np.where(far > 0, soft_limit(far, MAX_DRIFT[0], MAX_DRIFT[1]) / np.maximum(far, 1e-300), 1.0)
        weight[held] *= scale[held]
        offset[held] *= scale[held, None]
        raised[held] *= scale[held]
        pace_passes(held, weight, offset, raised, h, passes[0], STEP_LIFT * body, STAND_STEP * body, *passes[1:],
                    foot=np.concatenate([a_feet[1:, leg] * flat, horiz, b_feet[:1, leg] * flat]), rise=rise)
        swing_offsets(offset, contact_runs(held), passes[3])
        weights[:, leg] = weight
        locks.append((offset, raised, held))
    # The toes' floor: the context's; without one, a held foot's lowest toe in the new frames, or
    # the new frames' lowest toe when no foot is held. A toe under it is lifted out.
    if toe_floor == np.inf:
        for leg, (_, _, held) in enumerate(locks):
            if held.any():
                toe_floor = min(toe_floor, float(gpos[held, toes[leg], up].min()))
    if toe_floor == np.inf:
        toe_floor = float(gpos[:, toes, up].min())
    for leg, (thigh, shin, ankle) in enumerate(chains):
        offset, raised, held = locks[leg]
        # The toe where the ankle goes (the foot keeps its orientation), clear of the floor in the
        # air. A foot without a toe joint: its ankle kept out of the floor (its lowest in the
        # context), not lifted higher (an ankle swings low at heel strike).
        toe = gpos[:, toes[leg]] + offset
        toe[:, up] += raised
        raised += clearance_lift(toe, ~held, toe_floor, up, body, fps, TOE_CLEAR if toes[leg] != ankle else 0.0,
                                 clearance)
        frames = np.flatnonzero((offset != 0).any(axis=1) | (raised != 0))
        if len(frames) == 0:
            continue
        goal = gpos[:, ankle].copy()
        goal[frames] += offset[frames]
        goal[frames, up] = gpos[frames, ankle, up] + raised[frames]
        # The leg's hinge from the frames the lock moves; each frame's axis; the bounded turns.
        hinge = leg_hinge(gpos[frames, thigh], gpos[frames, shin], gpos[frames, ankle], grot[frames, thigh],
                          rots[frames, thigh], None if toes[leg] == ankle else gpos[frames, toes[leg]])
        axes = knee_axes(gpos[:, thigh], gpos[:, shin], gpos[:, ankle], grot[:, thigh], rots[:, thigh], hinge,
                         KNEE_HINGE)
        turn, bent = knee_bounded(goal, gpos[:, thigh], gpos[:, shin], gpos[:, ankle], axes, SOFT_REACH,
                                  KNEE_ACCEL / fps**2)
        frames = np.flatnonzero(bent | (offset != 0).any(axis=1) | (raised != 0))
        new_thigh, new_shin = hinge_ik(gpos[frames, thigh], gpos[frames, shin], gpos[frames, ankle], goal[frames],
                                       grot[frames, thigh], grot[frames, shin], rots[frames, thigh],
                                       rots[frames, shin], axes[frames], turn[frames], IK_EPS)
        foot_global = grot[frames, ankle]
        rots[frames, thigh] = new_thigh
        rots[frames, shin] = new_shin
        # Keep the foot's global orientation: its parent chain turned.
        thigh_global = quat.mul(grot[frames, int(sk.parents[thigh])], new_thigh)
        if sk.parents[shin] == thigh and sk.parents[ankle] == shin:
            ankle_parent = quat.mul(thigh_global, new_shin)
        else:  # twist joints between: they keep their local rotations and turn with the joint above
            shin_global = quat.mul(quat.mul(quat.mul(thigh_global, quat.inv(grot[frames, thigh])),
                                            grot[frames, int(sk.parents[shin])]), new_shin)
            ankle_parent = quat.mul(quat.mul(shin_global, quat.inv(grot[frames, shin])),
                                    grot[frames, int(sk.parents[ankle])])
        rots[frames, ankle] = quat.mul(quat.inv(ankle_parent), foot_global)
        # The legs share no joint: the next leg's chain is unchanged, no new FK needed.
    return weights

