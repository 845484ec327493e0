"""What joints are, from their names: legs, feet, hands, head; body parts; contact thresholds.
Legs and arms no name tells are read from the hierarchy (:class:`Limbs`).

Where the motion side reads joint names (BVH files name joints freely: ``LeftFoot``,
``l_ankle``, ``mixamorig:LeftToeBase``): everything that needs a leg, a foot or a hand asks
here (the maps' bone classes have their own rules, :mod:`posturemap.learn.features`). Names
are matched case-insensitively after any ``namespace:`` prefix.
"""

from __future__ import annotations

import re
from functools import lru_cache
from types import SimpleNamespace

import numpy as np

from .skeleton import Skeleton

# Foot contact thresholds, in leg lengths (thigh + shin bone, from the skeleton's offsets; 80 cm
# for Bandai), so that they hold for any unit and body size.
CONTACT_HEIGHT = 0.042  # above the foot's floor (about 3.4 cm on Bandai)
CONTACT_SPEED = 0.75  # leg lengths per second (about 60 cm/s on Bandai)

FOOT_PATTERN = re.compile(r"foot|toe|ankle|heel", re.IGNORECASE)  # every joint of a foot
_ANKLE = re.compile(r"foot|ankle", re.IGNORECASE)
_NOT_ANKLE = re.compile(r"toe|end", re.IGNORECASE)
# Twist and roll joints inside a limb (Daz's ``lThighBend > lThighTwist > lShin``, HumanIK's
# ``LeftUpLegRoll`` where a rig puts it in the chain): they turn the bone about its own axis,
# and a leg's chain passes through them to the joint above.
_TWIST = re.compile(r"twist|roll(?!er)", re.IGNORECASE)
_END = re.compile(r"end|nub|tip|site", re.IGNORECASE)  # a chain's last joint, past the bone it ends
_HAND = re.compile(r"hand|wrist", re.IGNORECASE)
_NOT_HAND = re.compile(r"thumb|index|middle|ring|pinky|finger|end|site", re.IGNORECASE)
_HEAD = re.compile(r"head", re.IGNORECASE)


def short_name(name: str) -> str:
    """A joint name without its ``namespace:`` prefix."""
    return name.split(":")[-1]


def ancestors(parents: np.ndarray, j: int) -> list[int]:
    """The joints above ``j``, top first."""
    chain = []
    p = int(parents[j])
    while p >= 0:
        chain.append(p)
        p = int(parents[p])
    return chain[::-1]


def foot_joints(names) -> np.ndarray:
    """Indices of the joints named like feet, ankles, toes or heels."""
    return np.array([j for j, n in enumerate(names) if FOOT_PATTERN.search(short_name(n))], dtype=np.int64)


def _is_ankle(name: str) -> bool:
    n = short_name(name)
    return bool(_ANKLE.search(n)) and not _NOT_ANKLE.search(n)


def subtree_mask(parents: np.ndarray, root: int) -> np.ndarray:
    """Bool (J,): ``root`` and its descendants (one pass: parents come before children); all
    False for ``root`` -1."""
    mask = np.zeros(len(parents), dtype=bool)
    if root >= 0:
        mask[root] = True
        for k in range(root + 1, len(parents)):
            p = parents[k]
            mask[k] = p >= 0 and mask[p]
    return mask


def _below_any(parents: np.ndarray, marked: np.ndarray) -> np.ndarray:
    """Bool (J,): the joints with a ``marked`` joint strictly above them (one pass)."""
    out = np.zeros(len(parents), dtype=bool)
    for k in range(len(parents)):
        p = parents[k]
        out[k] = p >= 0 and (out[p] or marked[p])
    return out


def _stem(name: str) -> str:
    """A joint's name without its numbers: the segments of one bone share it (MakeHuman's
    ``upperleg01.L``, ``upperleg02.L``; Rigify's ``DEF-shin.L``, ``DEF-shin.L.001``)."""
    return re.sub(r"[._\- ]+$", "", re.sub(r"\d+", "", short_name(name))).lower()


def leg_chains(sk: Skeleton) -> list[tuple[int, int, int]]:
    """(thigh, shin, ankle) joint indices of each leg: an ankle ("foot"/"ankle", not a toe or an
    end site, nor the child of such a joint: SMPL's ``L_Foot`` is the toe below ``L_Ankle``)
    whose parent and grandparent are the shin and the thigh.

    A bone may be several joints, passed through to the one at its top: twist and roll joints
    (by name; Daz's ``lThighBend > lThighTwist > lShin``) and the segments of a bone split in
    numbered parts (MakeHuman's ``upperleg01.L > upperleg02.L > lowerleg01.L > lowerleg02.L >
    foot.L``, Rigify's ``DEF-thigh.L > DEF-thigh.L.001 > DEF-shin.L > DEF-shin.L.001``): they
    keep their rotations and stay inside the thigh or the shin. Where that would leave no
    distinct thigh (every joint numbered alike, or thigh and shin named alike but for a number,
    so that two legs would share the hips as their thigh), the plain parent and grandparent.

    Where no leg is named so (joints named ``j0``, ``j1``..., or in another language), the legs
    of the hierarchy (:func:`structural_legs`).

    Found once per hierarchy (names, parents and offsets): an engine asks for each clip it
    prepares, and :func:`posturemap.synth.engine.transition` prepares two per call."""
    return list(_leg_chains_of(tuple(sk.names), np.asarray(sk.parents, dtype=np.int64).tobytes(),
                               np.asarray(sk.offsets, dtype=np.float64).tobytes()))


@lru_cache(maxsize=32)
def _leg_chains_of(names: tuple[str, ...], parents: bytes, offsets: bytes) -> tuple[tuple[int, int, int], ...]:
    sk = SimpleNamespace(names=names, parents=np.frombuffer(parents, dtype=np.int64), num_joints=len(names))
    chains = _leg_chains(sk, segments=True)
    if not chains:
        return tuple(structural_legs(sk.parents, np.frombuffer(offsets, dtype=np.float64).reshape(-1, 3)))
    # Bones told apart by number only (L_Leg1 > L_Leg2 > L_Foot) would run into the hips: a thigh
    # shared by two legs, or above another leg's, is no thigh. Then no segments are merged.
    thighs = [c[0] for c in chains]
    is_thigh = np.zeros(sk.num_joints, dtype=bool)
    is_thigh[thighs] = True
    if len(set(thighs)) < len(thighs) or _below_any(sk.parents, is_thigh)[thighs].any():
        chains = _leg_chains(sk, segments=False)
    return tuple(chains)


def _leg_chains(sk: Skeleton, segments: bool) -> list[tuple[int, int, int]]:
    """:func:`leg_chains`, passing through numbered segments (``segments``) or not; linear in
    the joints (a hostile file may hold thousands)."""
    parents, n = sk.parents, sk.num_joints
    ankle = np.array([_is_ankle(x) for x in sk.names], dtype=bool)
    twist = [bool(_TWIST.search(short_name(x))) for x in sk.names]
    stems = [_stem(x) for x in sk.names]
    up = np.full(n, -1, dtype=np.int64)  # each joint's parent in a limb's chain: past twist and roll joints
    top = np.arange(n)  # the first joint of the bone each joint belongs to (numbered segments)
    for k in range(n):
        p = int(parents[k])
        if p >= 0:
            up[k] = up[p] if twist[p] else p
            if segments and stems[k] and stems[p] == stems[k]:
                top[k] = top[p]
    out = []
    for j in np.flatnonzero(ankle).tolist():
        shin = int(up[j])
        if shin < 0 or ankle[shin]:
            continue
        first = int(top[shin])
        thigh = int(up[first])
        thigh = int(top[thigh]) if thigh >= 0 else -1
        if thigh < 0 or parents[thigh] < 0:  # the segments ran into the root: names do not tell
            first, thigh = shin, int(up[shin])
        if thigh >= 0:
            out.append((thigh, first, j))
    # A roll joint named like a foot above the ankle (LeftFootRoll > LeftFoot) is passed through
    # by the ankle below it: the leg is that ankle's, not the roll joint's.
    is_ankle = np.zeros(n, dtype=bool)
    is_ankle[[c[2] for c in out]] = True
    has_ankle_below = np.zeros(n, dtype=bool)
    for k in range(n - 1, 0, -1):  # children come after their parents
        p = parents[k]
        if p >= 0 and (has_ankle_below[k] or is_ankle[k]):
            has_ankle_below[p] = True
    return [c for c in out if not has_ankle_below[c[2]]]


LIMB_LIKE = 0.25  # two limbs' bones: each within this share of its twin's length
SHORT_BONE = 0.01  # of a chain's length: a joint this close to its parent (a twist or roll helper) is in its bone
HAND_OR_FOOT = 0.5  # of the forearm or shin: the bone below an ankle or a wrist is shorter


class Limbs:
    """The hierarchy's limbs, read without names (plain arrays of a skeleton's ``parents`` and
    ``offsets``): each joint's children, subtree size, depth and bone length (its offset's).

    :meth:`path` follows a chain down, :meth:`pairs` finds the alike chains among a joint's
    children, :meth:`joints3` the upper joint, the middle joint and the end of a limb (thigh,
    knee, ankle; upper arm, elbow, wrist). What :func:`structural_legs`, :func:`structural_arms`
    and the bone classes of :func:`posturemap.learn.features.assign_classes` read the same way."""

    def __init__(self, parents: np.ndarray, offsets: np.ndarray):
        parents = np.asarray(parents, dtype=np.int64)
        n = len(parents)
        self.parents = parents
        self.kids = [[] for _ in range(n)]
        for j in range(n):
            if parents[j] >= 0:
                self.kids[int(parents[j])].append(j)
        self.inner = [[k for k in ks if self.kids[k]] for ks in self.kids]  # children with children
        self.size = np.ones(n, dtype=np.int64)
        for j in range(n - 1, -1, -1):  # children come after their parents
            if parents[j] >= 0:
                self.size[parents[j]] += self.size[j]
        self.depth = np.zeros(n, dtype=np.int64)
        for j in range(n):
            if parents[j] >= 0:
                self.depth[j] = self.depth[parents[j]] + 1
        self.bone = np.linalg.norm(np.asarray(offsets, dtype=np.float64).reshape(n, 3), axis=1)
        self.forked = np.array([len(ks) >= 2 for ks in self.inner], dtype=bool)  # a fork at or below
        for j in range(n - 1, -1, -1):
            if parents[j] >= 0 and self.forked[j]:
                self.forked[parents[j]] = True
        # Per joint, its forked children and its three largest ones: beside_body in constant time.
        self._n_forked = [sum(1 for k in ks if self.forked[k]) for ks in self.kids]
        self._largest = [sorted(ks, key=lambda k: -self.size[k])[:3] for ks in self.kids]

    def path(self, c: int) -> list[int]:
        """The joints from ``c`` down single children that have children (a leaf beside the
        chain, a twist helper's, is passed by) to a leaf, the longest bone of several, or to a
        fork (a hand with fingers, a foot with toes), which ends it. Chains that start at
        different children of a fork never overlap."""
        out = [c]
        while len(self.inner[out[-1]]) == 1:
            out.append(self.inner[out[-1]][0])
        if not self.inner[out[-1]] and self.kids[out[-1]]:
            out.append(max(self.kids[out[-1]], key=lambda k: (self.bone[k], -k)))
        return out

    def reach(self, path: list[int]) -> float:
        """The chain's length: its bones summed."""
        return float(self.bone[path[1:]].sum())

    def pairs(self, paths: list[list[int]]) -> list[tuple[int, int]]:
        """Indices into ``paths`` of alike chains of three joints or more: as many joints once
        those in their parent's bone are left out (:meth:`_bones`), each bone within
        :data:`LIMB_LIKE` of its twin's. Those of one length are compared in order of their
        total length, each with the next (not every pair: a hostile joint may have thousands
        of children)."""
        bone = self.bone
        kept = [self._bones(x) for x in paths]
        order = sorted(range(len(paths)), key=lambda i: (len(kept[i]), self.reach(paths[i]), paths[i][0]))
        out = []
        for i, k in zip(order, order[1:]):
            x, y = kept[i], kept[k]
            if len(x) == len(y) >= 3 and all(abs(bone[a] - bone[b]) <= LIMB_LIKE * max(bone[a], bone[b])
                                             for a, b in zip(x[1:], y[1:])):
                out.append((i, k))
        return out

    def _bones(self, path: list[int]) -> list[int]:
        """The chain without the joints that sit in their parent's bone (a twist or roll helper
        at the parent's place: a bone under :data:`SHORT_BONE` of the chain's length)."""
        least = SHORT_BONE * self.reach(path)
        return path[:1] + [j for j in path[1:] if self.bone[j] > least]

    def joints3(self, path: list[int]) -> tuple[int, int, int]:
        """The upper joint, the middle joint and the end of a limb of three joints or more:
        the two longest consecutive bones (thigh and shin; upper arm and forearm) of those
        whose end is followed by nothing or by a bone under :data:`HAND_OR_FOOT` of the lower
        one (a foot, a hand: CMU's clavicle, longer than its forearm, is not the upper arm),
        helpers in a parent's bone left out (:meth:`_bones`). A hip joint or a clavicle above
        and the toes or fingers below fall outside."""
        q, bone = self._bones(path), self.bone
        ks = range(1, len(q) - 1)
        ended = [k for k in ks if k + 2 >= len(q) or bone[q[k + 2]] < HAND_OR_FOOT * bone[q[k + 1]]]
        k = max(ended or ks, key=lambda k: (bone[q[k]] + bone[q[k + 1]], -k))
        return q[k - 1], q[k], q[k + 1]

    def legs(self) -> list[tuple[int, int, int]]:
        """(thigh, shin, ankle) of each leg: of the alike pairs of chains that leave one joint
        (:meth:`pairs`) beside the body (:meth:`beside_body`: the spine forks into the arms and
        the neck), the one that reaches furthest (legs outreach arms, a skirt's chains,
        fingers). The thigh, knee and ankle by :meth:`joints3`, so that a hip joint above the
        thigh (CMU's ``LHipJoint``) and the toes below the ankle fall outside, a twist helper at
        its parent's place too (one halfway down a bone splits it: a rig that names nothing and
        has those is read wrongly). [] where no such pair is found. Near-linear in the joints (a
        hostile file may hold thousands): chains from different joints do not overlap."""
        best, legs = -1.0, []
        for p in range(len(self.kids)):
            if len(self.inner[p]) < 2:
                continue
            paths = [self.path(c) for c in self.inner[p]]
            for i, k in self.pairs(paths):
                x, y = paths[i], paths[k]
                reach = self.reach(x) + self.reach(y)
                if reach > best and self.beside_body(p, x[0], y[0]):
                    best, legs = reach, sorted((self.joints3(x), self.joints3(y)))
        return legs

    def beside_body(self, p: int, c: int, d: int) -> bool:
        """Whether chains ``c`` and ``d`` from joint ``p`` hang beside the body: another child of
        ``p``, or of ``p``'s parent (a pelvis beside the spine), forks below (the spine into the
        arms and the neck) or holds at least as many joints as the two together. Not so a hand's
        fingers, beside other fingers."""
        need = self.size[c] + self.size[d]
        if self._n_forked[p] > self.forked[c] + self.forked[d]:
            return True
        if any(self.size[o] >= need for o in self._largest[p] if o not in (c, d)):
            return True
        q = self.parents[p]
        return bool(q >= 0 and (self._n_forked[q] > self.forked[p]
                                or any(self.size[o] >= need for o in self._largest[q] if o != p)))


def structural_legs(parents: np.ndarray, offsets: np.ndarray) -> list[tuple[int, int, int]]:
    """(thigh, shin, ankle) of each leg read from the hierarchy alone, for a rig whose names say
    nothing (:meth:`Limbs.legs`)."""
    return Limbs(parents, offsets).legs()


def structural_arms(sk: Skeleton, legs) -> list[tuple[int, int, int]]:
    """(upper arm, forearm, hand) of each arm read from the hierarchy alone, for a rig whose names
    say nothing: the alike pair of chains (:meth:`Limbs.pairs`; a chain may end at a fork, a hand
    with fingers) that reaches furthest among those leaving the joint nearest the top of the
    body (below :func:`posturemap.core.motion.root_index`, not the IK targets a game rig keeps
    beside it), other than the one the ``legs`` ((thigh, shin, ankle) each) hang from and
    outside them (the shoulders at the chest); the upper arm, elbow and wrist by
    :meth:`Limbs.joints3` (a clavicle above falls outside). [] without two legs, or where no such pair is found."""
    from .motion import root_index

    hips = legs_root(sk, legs)
    if hips < 0:
        return []
    parents = np.asarray(sk.parents, dtype=np.int64)
    in_legs = np.zeros(len(parents), dtype=bool)
    for leg in legs:
        in_legs |= subtree_mask(parents, leg[0])
    below = subtree_mask(parents, root_index(sk))  # the body: beside a pelvis the spine, not IK targets
    limbs = Limbs(parents, sk.offsets)
    forks = [j for j in range(len(parents)) if len(limbs.inner[j]) >= 2 and below[j] and j != hips and not in_legs[j]]
    for p in sorted(forks, key=lambda j: (limbs.depth[j], j)):
        paths = [limbs.path(c) for c in limbs.inner[p] if not in_legs[c]]
        found = limbs.pairs(paths)
        if found:
            i, k = max(found, key=lambda ik: limbs.reach(paths[ik[0]]) + limbs.reach(paths[ik[1]]))
            return sorted((limbs.joints3(paths[i]), limbs.joints3(paths[k])))
    return []


def _rest_distance(sk: Skeleton, top: int, j: int) -> float:
    """The rest pose's distance from joint ``top`` to its descendant ``j`` (the offsets between
    them summed)."""
    v = np.zeros(3)
    while j != top and j >= 0:
        v += sk.offsets[j]
        j = int(sk.parents[j])
    return float(np.linalg.norm(v))


def leg_toes(sk: Skeleton, chains=None) -> np.ndarray:
    """The toe joint of each leg (n_legs,): the ankle's child with the longest bone (``Toes_L``,
    ``LeftToeBase``), on down while that joint has a single child not named like an end (Daz's
    ``lFoot > lMetatarsals > lToe``: the toe, not the middle of the foot; Mixamo's ``LeftToeBase``
    keeps its ``LeftToe_End`` below), or the ankle itself where it has no child. ``chains``
    defaults to :func:`leg_chains`."""
    chains = leg_chains(sk) if chains is None else chains
    has_parent = sk.parents >= 0
    n_kids = np.bincount(sk.parents[has_parent], minlength=sk.num_joints)
    last_kid = np.full(sk.num_joints, -1, dtype=np.int64)  # a joint's only child, where it has one
    last_kid[sk.parents[has_parent]] = np.flatnonzero(has_parent)
    toes = []
    for _, _, ankle in chains:
        kids = sk.children(ankle)
        if not kids:
            toes.append(ankle)
            continue
        toe = kids[int(np.argmax(np.linalg.norm(sk.offsets[kids], axis=-1)))]
        while n_kids[toe] == 1 and not _END.search(short_name(sk.names[last_kid[toe]])):
            toe = int(last_kid[toe])
        toes.append(toe)
    return np.array(toes, dtype=np.int64)


def describe_legs(sk: Skeleton) -> list[list[str]]:
    """Each leg found by name as its joints' names, thigh to toe (the toe left out where the ankle
    has none): what the foot lock moves and what retrieval's lower body holds."""
    chains = leg_chains(sk)
    return [[sk.names[j] for j in chain] + ([sk.names[toe]] if toe != chain[2] else [])
            for chain, toe in zip(chains, leg_toes(sk, chains).tolist())]


LEGS_MISSING = ("none found by name (an ankle named foot or ankle, under a shin and a thigh) nor in the hierarchy "
                "(two like chains of three joints or more beside the spine): no foot lock, "
                "and retrieval's lower body is the root alone")


def leg_length(sk: Skeleton, chains=None) -> float:
    """Mean thigh + shin bone length of the legs (from the offsets, through any twist joints
    between), in the skeleton's unit; 1.0 without legs, or where every leg found has no length
    (a rig whose offsets are all zero: speeds and distances are divided by this).
    ``chains`` defaults to :func:`leg_chains`."""
    chains = leg_chains(sk) if chains is None else chains
    lengths = [_rest_distance(sk, thigh, shin) + _rest_distance(sk, shin, ankle) for thigh, shin, ankle in chains]
    lengths = [x for x in lengths if x > 0.0]
    return float(np.mean(lengths)) if lengths else 1.0


def legs_root(sk: Skeleton, chains=None) -> int:
    """The joint the legs hang from: the deepest joint above (or at) every thigh of
    :func:`leg_chains` (the hips, or the pelvis); -1 with fewer than two legs."""
    chains = leg_chains(sk) if chains is None else chains
    if len(chains) < 2:
        return -1
    count = np.zeros(sk.num_joints, dtype=np.int64)  # the thighs at or below each joint
    for thigh, _, _ in chains:
        count[thigh] += 1
    for k in range(sk.num_joints - 1, 0, -1):
        if sk.parents[k] >= 0:
            count[sk.parents[k]] += count[k]
    common = np.flatnonzero(count == len(chains))
    return int(common[np.argmax(sk.depth()[common])]) if len(common) else -1


def named_hands_and_head(sk: Skeleton) -> tuple[list[int], list[int]]:
    """The joints named like a hand or wrist (not a finger) and like a head."""
    names = [short_name(n) for n in sk.names]
    return ([j for j, n in enumerate(names) if _HAND.search(n) and not _NOT_HAND.search(n)],
            [j for j, n in enumerate(names) if _HEAD.search(n) and not _NOT_HAND.search(n)])


def arm_chains(sk: Skeleton) -> list[tuple[int, int, int]]:
    """(upper arm, forearm, hand) joint indices of each arm: a joint named like a hand or wrist
    (:func:`named_hands_and_head`; the top one where a wrist holds a hand), among the body's
    joints (as :func:`key_joints`: not a game rig's IK targets beside it), whose parent and
    grandparent, past twist and roll joints, are the forearm and the upper arm. Where no hand is
    named, the hierarchy's arms (:func:`structural_arms`)."""
    from .motion import root_index

    parents, n = sk.parents, sk.num_joints
    body = subtree_mask(parents, root_index(sk))
    hands = [j for j in named_hands_and_head(sk)[0] if body[j]]
    if not hands:  # none named: the hierarchy's
        return structural_arms(sk, leg_chains(sk))
    is_hand = np.zeros(n, dtype=bool)
    is_hand[hands] = True
    twist = [bool(_TWIST.search(short_name(x))) for x in sk.names]
    up = np.full(n, -1, dtype=np.int64)  # each joint's parent in a limb's chain: past twist and roll joints
    below_hand = np.zeros(n, dtype=bool)
    for k in range(n):  # parents come first
        p = int(parents[k])
        if p >= 0:
            up[k] = up[p] if twist[p] else p
            below_hand[k] = below_hand[p] or is_hand[p]
    out = []
    for hand in hands:
        if below_hand[hand]:
            continue
        forearm = int(up[hand])
        upper = int(up[forearm]) if forearm >= 0 else -1
        if upper >= 0 and parents[upper] >= 0 and body[upper] and not is_hand[forearm]:
            out.append((upper, forearm, hand))
    return out


def head_below(parents: np.ndarray, hand_a: int, hand_b: int, excluded: np.ndarray) -> int:
    """The head of a rig that names its hands but not its head: from the joint where the two
    hands' arms meet (their deepest common ancestor, the chest), down its child with the most
    joints below it that is neither arm's first joint nor ``excluded`` (bool (J,), the legs),
    then down single children to a leaf or to a joint that branches (a head with face joints);
    -1 when the arms do not meet below the hands or the chest has no other child. Linear in the
    number of joints (parents come before children)."""
    a = ancestors(parents, hand_a) + [hand_a]
    b = ancestors(parents, hand_b) + [hand_b]
    k = 0
    while k < min(len(a), len(b)) and a[k] == b[k]:
        k += 1
    if k == 0 or k == len(a) or k == len(b):
        return -1
    chest, arms = a[k - 1], {a[k], b[k]}
    n = len(parents)
    size = np.ones(n, dtype=np.int64)  # joints in each subtree
    kids = [[] for _ in range(n)]
    for j in range(n - 1, -1, -1):
        p = int(parents[j])
        if p >= 0:
            size[p] += size[j]
            kids[p].append(j)
    options = [c for c in kids[chest] if c not in arms and not excluded[c]]
    if not options:
        return -1
    j = max(options, key=lambda c: (size[c], -c))
    while len(kids[j]) == 1:
        j = kids[j][0]
    return int(j)


def head_joint(sk: Skeleton) -> int:
    """The head among :func:`key_joints`' upper joints (its last, when found by name or as the
    top of the neck chain); -1 where the skeleton names no head and no two hands."""
    return _key_joints(sk)[2]


def key_joints(sk: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Joints matched by retrieval: ``lower`` (ankles, knees) and ``upper`` (wrists, head).

    Found by name (the legs of :func:`leg_chains`; "hand"/"wrist" without a finger word, the one
    nearest the root of a chain of them, as SMPL's ``L_Wrist`` above ``L_Hand``; "head"), among
    the body's joints (below the root of :func:`posturemap.core.motion.root_index`: not the IK
    targets a game rig keeps beside the body, as UE's ``ik_hand_root``); a rig that names its
    hands but not its head (Rigify's ``DEF-spine.006``) gets the top of its neck chain
    (:func:`head_below`); a rig that names no hand, the hands of the hierarchy's arms
    (:func:`structural_arms`) and the head above them so; where a skeleton has neither, the
    leaves outside the legs.
    """
    lower, upper, _ = _key_joints(sk)
    return lower, upper


def _key_joints(sk: Skeleton):
    from .motion import root_index

    chains = leg_chains(sk)
    lower = [c[2] for c in chains] + [c[1] for c in chains]
    leg_joints = {j for c in chains for j in c}
    names = [short_name(n) for n in sk.names]
    body = subtree_mask(sk.parents, root_index(sk))
    hands, heads = named_hands_and_head(sk)
    is_hand = np.zeros(sk.num_joints, dtype=bool)
    is_hand[hands] = True
    below_hand = _below_any(sk.parents, is_hand)
    upper = [j for j in hands if body[j] and not below_hand[j]]
    if not upper:  # no hand named: the hierarchy's arms' (structural_arms)
        upper = [arm[2] for arm in structural_arms(sk, chains) if body[arm[2]]]
    head = [j for j in heads if body[j]][:1]
    if not head and len(upper) >= 2:
        in_legs = np.zeros(sk.num_joints, dtype=bool)
        for c in chains:
            in_legs |= subtree_mask(sk.parents, c[0])
        top = head_below(sk.parents, upper[0], upper[1], in_legs)
        head = [top] if top >= 0 and body[top] else []
    upper += head
    if not upper:  # no names: the leaves outside the legs
        leaves = [j for j in range(sk.num_joints) if not sk.children(j) and j not in leg_joints]
        upper = leaves[:3]
    return np.array(lower, dtype=np.int64), np.array(upper, dtype=np.int64), (head[0] if head else -1)


def part_masks(sk: Skeleton, root: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint masks (J,) of the two body parts: ``lower`` (the root and the legs' subtrees: the
    root carries the trajectory) and ``upper`` (the root's other descendants: spine, arms,
    head). Joints above the root (a reference node) are in neither."""
    j = sk.num_joints
    lower = np.zeros(j, dtype=bool)
    for thigh, _, _ in leg_chains(sk):
        lower[thigh] = True
    for k in range(j):  # parents come first
        p = sk.parents[k]
        if p >= 0:
            lower[k] |= lower[p]
    below = subtree_mask(sk.parents, root)
    lower[root] = True
    return lower & below, below & ~lower


def upper_tops(parents: np.ndarray, root: int, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """The upper body's top joints (:func:`part_masks`' ``upper`` whose parent is ``root``: the
    spine's first) that carry no leg: a hip joint between the root and a thigh (CMU's
    ``LHipJoint``), in the upper body by the masks, is not one, since turning it moves the legs."""
    parents = np.asarray(parents)
    tops = np.flatnonzero(upper & (parents == root))
    return np.array([t for t in tops.tolist() if not (subtree_mask(parents, t) & lower).any()], dtype=np.int64)
