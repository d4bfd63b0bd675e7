"""The fuzzy logic controller of Pratihar, Deb & Ghosh (1999): the paper's distance and
angle of the most critical obstacle in, the deviation from the goal direction and the
speed out.

**Terms.** Distance: VN (very near), NR (near), FR (far), VF (very far), centred at 0,
1, 2, 3 × ``distance_step_cm``. Angle (obstacle from the goal direction,
counter-clockwise positive): LT (left), AL (ahead left), AH (ahead), AR (ahead right),
RT (right), centred at 2, 1, 0, −1, −2 × ``angle_step_deg``. Deviation (the robot's
heading from the goal direction): the same five terms at ``deviation_step_deg``
apart. Speed: VS, SL (slow), FT (fast), VF, evenly from ``slowest`` × the top speed to
the top speed. Each term is a triangle reaching its neighbours' centres (so the
spacing is the variable's scaling factor, the relative spacing constant, as the
paper's GA tunes it); the outer ones stay 1 beyond their centre.

**Rules.** One per (distance, angle) pair, 20 in all: "if distance is D and angle is A
then deviation is X and speed is S", each on or off. Inference: a rule fires with the
smaller of its two memberships; the outputs are the firing-weighted means of the
consequents' centres (centre of sums with triangles of equal width). Inputs exactly
at a term's centre whose rules are off (an obstacle dead ahead when the "ahead" rules
are off) fire nothing there; the output is then the limit from beside them (the angle a
hair to the left, the distance a hair nearer: :data:`NUDGE`), so that no gap in the rules
lets a robot drive on at an obstacle. When no rule fires even so, the robot heads for
its goal at top speed.

**The arena's edge** (:mod:`.steering`, :mod:`.sides`): how near an edge (cm beyond the
robot's radius) the heading loses its outward part (``edge_cm``), how much of the speed
goes with the heading taken away (``edge_slow``), and whether the rules see their
inputs in a frame whose left is the side the arena leaves more room on
(``side_by_room``). Their defaults are the edge rule of the controllers tuned without
them.

**The guard** (:mod:`.guard`): the controller's wish checked against every body, not
the critical one only, and changed for an evasive one when its time to contact is
shorter than ``guard_s`` (0, the default: no guard, the controllers tuned without it).

**Designer's controller** (:func:`designer`, the untuned one): all 20 rules on, an
obstacle near and to one side turns the robot to the other side and slows it, one
ahead turns it right, one far or very far lets it go; scaling 20 cm, 45°, 45°, a 10 %
slowest speed, predictions 0.5 s ahead (not at the closest approach), the edge rule's
defaults, no guard. ``ovis navigate --tune`` tunes the scaling, the look-ahead and how
it is used, the edge's three, the guard, which rules are on and their consequents with
ovis's GA (:mod:`ovis.common.navigation.tuning`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.atomic import write_atomic
from ovis.common.navigation.steering import EDGE_CM

__all__ = [
    "ANGLE_TERMS",
    "DEVIATION_TERMS",
    "DISTANCE_TERMS",
    "SPEED_TERMS",
    "FuzzyArrays",
    "FuzzyParams",
    "Rule",
    "designer",
    "infer",
    "infer_arrays",
    "load_fuzzy",
    "memberships",
    "save_fuzzy",
    "tuned_default",
]

DISTANCE_TERMS = ("VN", "NR", "FR", "VF")
ANGLE_TERMS = ("LT", "AL", "AH", "AR", "RT")
DEVIATION_TERMS = ANGLE_TERMS
SPEED_TERMS = ("VS", "SL", "FT", "VF")

#: How far beside a term's centre an input that fires no rule is taken again (degrees
#: to the left, cm nearer): the output's limit from there (module docstring).
NUDGE = 1e-3

#: Where each term's centre is, in steps of its variable's scaling.
_DISTANCE_AT = np.array([0.0, 1.0, 2.0, 3.0])
_ANGLE_AT = np.array([2.0, 1.0, 0.0, -1.0, -2.0])

#: The shipped tuned controller (``ovis navigate --tune``'s output).
TUNED_FILE = Path(__file__).with_name("fuzzy_tuned.json")

FloatArray = NDArray[np.float64]


class Rule(msgspec.Struct, frozen=True, kw_only=True):
    """If distance is ``distance`` and angle is ``angle`` then deviation is
    ``deviation`` and speed is ``speed`` (when ``on``)."""

    distance: Literal["VN", "NR", "FR", "VF"]
    angle: Literal["LT", "AL", "AH", "AR", "RT"]
    deviation: Literal["LT", "AL", "AH", "AR", "RT"]
    speed: Literal["VS", "SL", "FT", "VF"]
    on: bool = True


class FuzzyParams(msgspec.Struct, frozen=True, kw_only=True):
    """One fuzzy controller: the four scaling factors, the look-ahead of the critical
    obstacle's prediction, the rule base; what tuned it (module docstring)."""

    distance_step_cm: Annotated[float, msgspec.Meta(gt=0.0, le=1000.0)]
    angle_step_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)]
    deviation_step_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)]
    slowest: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
    lookahead_s: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)]
    rules: Annotated[list[Rule], msgspec.Meta(min_length=20, max_length=20)]
    #: the critical body taken at its closest approach within the look-ahead
    #: (:mod:`.critical`), not at the look-ahead
    closest_approach: bool = False
    #: the arena's edge (module docstring)
    edge_cm: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = EDGE_CM
    edge_slow: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.0
    side_by_room: bool = False
    #: the guard: a wish whose time to contact is shorter than this (s) is changed for
    #: an evasive one (:mod:`.guard`; 0: no guard)
    guard_s: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.0
    #: how it was made: "designer", or the tuning's settings and figures
    origin: str = "designer"

    def __post_init__(self) -> None:
        pairs = {(r.distance, r.angle) for r in self.rules}
        if len(pairs) != 20:
            raise ValueError("rules: exactly one rule per (distance, angle) pair")

    def tables(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
        """The rule base as (4, 5) arrays of consequent indices (deviation, speed) and
        whether each rule is on, indexed [distance term, angle term]."""
        dev = np.zeros((4, 5), dtype=np.int64)
        spd = np.zeros((4, 5), dtype=np.int64)
        on = np.zeros((4, 5), dtype=bool)
        for r in self.rules:
            i, j = DISTANCE_TERMS.index(r.distance), ANGLE_TERMS.index(r.angle)
            dev[i, j] = DEVIATION_TERMS.index(r.deviation)
            spd[i, j] = SPEED_TERMS.index(r.speed)
            on[i, j] = r.on
        return dev, spd, on


#: The designer's rule base: (deviation, speed) per distance row, angle column
#: (LT, AL, AH, AR, RT).
_DESIGNER = {
    "VN": (("AR", "SL"), ("RT", "VS"), ("RT", "VS"), ("LT", "VS"), ("AL", "SL")),
    "NR": (("AH", "FT"), ("AR", "SL"), ("RT", "SL"), ("AL", "SL"), ("AH", "FT")),
    "FR": (("AH", "VF"), ("AH", "FT"), ("AR", "FT"), ("AH", "FT"), ("AH", "VF")),
    "VF": (("AH", "VF"),) * 5,
}


def designer() -> FuzzyParams:
    """The untuned controller (module docstring)."""
    rules = [
        Rule(distance=d, angle=a, deviation=dev, speed=spd)  # type: ignore[arg-type]
        for d, row in _DESIGNER.items()
        for a, (dev, spd) in zip(ANGLE_TERMS, row, strict=True)
    ]
    return FuzzyParams(
        distance_step_cm=20.0,
        angle_step_deg=45.0,
        deviation_step_deg=45.0,
        slowest=0.1,
        lookahead_s=0.5,
        rules=rules,
    )


class FuzzyArrays(NamedTuple):
    """B controllers as arrays (one per row: a batch may hold a GA's population):
    scalings and look-ahead (B,), the rule base (B, 4, 5) (:meth:`FuzzyParams.tables`),
    the edge's settings, how the critical body is taken and the guard's time (B,)."""

    distance_step: FloatArray
    angle_step: FloatArray
    deviation_step: FloatArray
    slowest: FloatArray
    lookahead: FloatArray
    deviation: NDArray[np.int64]
    speed: NDArray[np.int64]
    on: NDArray[np.bool_]
    edge_cm: FloatArray
    edge_slow: FloatArray
    side_by_room: NDArray[np.bool_]
    closest_approach: NDArray[np.bool_]
    guard: FloatArray

    @classmethod
    def of(cls, p: FuzzyParams, b: int = 1) -> FuzzyArrays:
        """``p`` repeated ``b`` times."""
        dev, spd, on = p.tables()
        scalars = (p.distance_step_cm, p.angle_step_deg, p.deviation_step_deg, p.slowest,
                   p.lookahead_s)  # fmt: skip
        return cls(
            *(np.full(b, v, dtype=float) for v in scalars),
            np.broadcast_to(dev, (b, 4, 5)),
            np.broadcast_to(spd, (b, 4, 5)),
            np.broadcast_to(on, (b, 4, 5)),
            np.full(b, p.edge_cm, dtype=float),
            np.full(b, p.edge_slow, dtype=float),
            np.full(b, p.side_by_room, dtype=bool),
            np.full(b, p.closest_approach, dtype=bool),
            np.full(b, p.guard_s, dtype=float),
        )

    def take(self, rows: NDArray[np.int64]) -> FuzzyArrays:
        """The controllers of ``rows``, in that order."""
        return FuzzyArrays(*(np.asarray(f)[rows] for f in self))


def memberships(x: FloatArray, centres: FloatArray, step: FloatArray) -> FloatArray:
    """(B, K) membership of each of B values in K triangular terms centred at
    ``centres`` (K,) × ``step`` (B,) (module docstring)."""
    x = np.asarray(x, float)[:, None]
    step = np.asarray(step, float).reshape(-1, 1)
    c = centres[None, :] * step
    mu = np.clip(1.0 - np.abs(x - c) / step, 0.0, 1.0)
    lo, hi = int(np.argmin(centres)), int(np.argmax(centres))
    mu[:, lo] = np.where(x[:, 0] <= c[:, lo], 1.0, mu[:, lo])
    mu[:, hi] = np.where(x[:, 0] >= c[:, hi], 1.0, mu[:, hi])
    return mu


def _fired(
    f: FuzzyArrays, distance_cm: FloatArray, angle_deg: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(B, 4, 5) firing strength of every rule, and (B,) their sum."""
    mu_d = memberships(distance_cm, _DISTANCE_AT, f.distance_step)
    mu_a = memberships(angle_deg, _ANGLE_AT, f.angle_step)
    w = np.minimum(mu_d[:, :, None], mu_a[:, None, :]) * f.on  # (B, 4, 5)
    return w, w.sum(axis=(1, 2))


def infer_arrays(
    f: FuzzyArrays, distance_cm: FloatArray, angle_deg: FloatArray, top_speed: float
) -> tuple[FloatArray, FloatArray]:
    """Deviation (deg) and speed (cm/s) of B controllers for B pairs of inputs (module
    docstring)."""
    w, total = _fired(f, distance_cm, angle_deg)
    if not np.all(total > 0):  # on a centre whose rules are off: the limit from beside
        beside_w, beside_total = _fired(
            f, np.asarray(distance_cm, float) - NUDGE, np.asarray(angle_deg, float) + NUDGE
        )
        none = total <= 0
        w = np.where(none[:, None, None], beside_w, w)
        total = np.where(none, beside_total, total)
    dev_at = _ANGLE_AT[f.deviation] * f.deviation_step[:, None, None]
    slow = f.slowest[:, None, None]
    speeds = top_speed * (slow + (1.0 - slow) * f.speed / 3.0)
    fired = total > 0
    safe = np.where(fired, total, 1.0)
    deviation = (w * dev_at).sum(axis=(1, 2)) / safe
    speed = (w * speeds).sum(axis=(1, 2)) / safe
    return np.where(fired, deviation, 0.0), np.where(fired, speed, top_speed)


def infer(
    p: FuzzyParams, distance_cm: FloatArray, angle_deg: FloatArray, top_speed: float
) -> tuple[FloatArray, FloatArray]:
    """:func:`infer_arrays` of one controller for B pairs of inputs."""
    b = np.asarray(distance_cm).size
    return infer_arrays(FuzzyArrays.of(p, b), distance_cm, angle_deg, top_speed)


def save_fuzzy(path: Path | str, params: FuzzyParams) -> None:
    """Write a controller as JSON (atomically)."""
    write_atomic(Path(path), msgspec.json.format(msgspec.json.encode(params), indent=2) + b"\n")


def load_fuzzy(path: Path | str) -> FuzzyParams:
    """A controller from its JSON file; ValueError saying what is wrong."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read the fuzzy planner {path}: {exc}") from None
    try:
        return msgspec.json.decode(data, type=FuzzyParams)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise ValueError(f"{path} is not a fuzzy planner file: {exc}") from None


def tuned_default() -> FuzzyParams:
    """The tuned controller shipped with ovis (the designer's if none ships)."""
    if TUNED_FILE.is_file():
        return load_fuzzy(TUNED_FILE)
    return designer()
