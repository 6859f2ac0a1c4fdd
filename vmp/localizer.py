"""Localization in a saved map without a starting pose: propose, verify, decide, track.

Every scan, each hypothesis of where the robot is (a pose filter of its own) moves by the
odometry increment (:mod:`vmp.frontend`) and is registered against the submap of the saved
milestone nearest it (:mod:`vmp.places`): a close fit within its filter's gate corrects it, a
scan without one is a miss. Until one hypothesis is trusted, the milestone signatures propose
places every few scans (:mod:`vmp.relocalization`); a proposal that agrees with a hypothesis
is one more find for it, any other starts a new one.

How well a scan fits a hypothesis is the mean likelihood of its points in the submap's search
grid at the registered pose (the branch-and-bound score). A scan fits when ICP fits closely,
within the hypothesis's gate, and it scores at least :data:`KEEP_RATIO` of what the hypothesis
usually scores (a robot carried to a look-alike corridor still registers against the old
one's walls, but its doors and ends no longer score). The robot is localized on a hypothesis
found :data:`MIN_FINDS` times that fits now, while no other place that fits scores within
:data:`RIVAL_RATIO` of it over the last few scans (then it is ambiguous: a corridor's
pilasters all look alike, and the right one cannot be told from the others). In the
simulated office the right place scores 0.998 (median; 0.98 at the tenth percentile), wrong
ones that ICP still fits 0.67 (0.84 at the ninetieth). It stays localized while
the scans fit; after :data:`LOST_AFTER` misses in a row it is lost: the hypothesis keeps
moving with odometry (the robot may just be looking into a room the map never saw) and takes
over again when the scans fit again, while the search looks for the place anew (the robot may
have been carried elsewhere, the kidnapped robot), and a place it finds often enough, that
fits, takes over.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from vmp.config import MappingConfig
from vmp.frontend import FrontEnd
from vmp.fusion import CHI2_3DOF_99, PoseFilter
from vmp.places import Places
from vmp.registration import MIN_POINTS, fits, register
from vmp.relocalization import Proposal, propose
from vmp.types import FloatArray, ScanFrame, compose, relative, rotate_covariance

__all__ = ["Hypothesis", "Localizer", "State"]

MIN_FINDS = 3  # proposals that must agree on a place before it is trusted
SEARCH_EVERY = 2  # scans between searches while not localized
LOST_AFTER = 3  # misses in a row after which the robot is lost
DROP_AFTER = 3  # misses in a row after which an untrusted hypothesis is dropped
DEAD_RECKONING = 100  # misses in a row after which a trusted one is dropped too
SAME_XY = 0.3  # a proposal this near a hypothesis (m) ...
SAME_THETA = math.radians(5.0)  # ... and turned this little agrees with it
MAX_HYPOTHESES = 8  # the most places followed at once (fewest finds dropped)
WINDOW = 10  # scans over which hypotheses are compared
KEEP_RATIO = 0.8  # a scan scoring less than this share of a hypothesis's usual is a miss
RIVAL_RATIO = 0.9  # a place scoring this share of the best's is a rival
REACH = 20.0  # live points scored: within this range (the submaps' reach, m)
# How well a proposal's pose is known when a hypothesis starts from it (m, m, rad).
PROPOSAL_SIGMA = (0.1, 0.1, math.radians(2.0))


class State(Enum):
    """What the localizer knows after a scan."""

    SEARCHING = "searching"  # no place found yet, or several that fit as well
    AMBIGUOUS = "ambiguous"  # more than one place fits and was found about as often
    LOCALIZED = "localized"  # one place, trusted, and the scan fits there
    LOST = "lost"  # was localized, the scans stopped fitting


@dataclass
class Hypothesis:
    """A place the robot may be: its filter, how often the search found it, its fits."""

    filter: PoseFilter
    finds: int = 1
    misses: int = 0  # scans in a row that did not fit
    fits: int = 0  # scans that fitted
    trusted: bool = False  # the localizer has declared it
    since: int = 0  # the scan it was first proposed at
    history: list[int] = field(default_factory=list)  # milestones it was found at
    scores: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW))  # 0: a miss
    fitted: deque[float] = field(default_factory=lambda: deque(maxlen=2 * WINDOW))

    @property
    def pose(self) -> FloatArray:
        return self.filter.pose

    @property
    def score(self) -> float:
        """Mean score over the last :data:`WINDOW` scans (a miss counts 0)."""
        return float(np.mean(self.scores)) if self.scores else 0.0

    @property
    def usual(self) -> float:
        """The median score of its recent fitting scans (0 before the first)."""
        return float(np.median(self.fitted)) if self.fitted else 0.0


@dataclass(frozen=True)
class Step:
    """The outcome of one scan."""

    state: State
    pose: FloatArray | None  # the localized pose in the map frame (None unless localized)
    hypotheses: list[FloatArray]  # every place followed, best first
    proposals: list[Proposal]  # the places the search proposed this scan


class Localizer:
    """Localizes scan after scan in a saved map (``places``)."""

    def __init__(self, places: Places, config: MappingConfig | None = None,
                 initial_pose: FloatArray | None = None) -> None:
        self.places = places
        self.config = config or MappingConfig()
        self.front = FrontEnd(self.config)
        self.stats: Counter[str] = Counter()
        self.hypotheses: list[Hypothesis] = []
        self.scan = -1
        self._last_search = -SEARCH_EVERY
        self.state = State.SEARCHING
        if initial_pose is not None:
            h = self._start(np.asarray(initial_pose, dtype=np.float64),
                            np.diag([0.3**2, 0.3**2, math.radians(10.0) ** 2]), 0)
            h.finds = MIN_FINDS
            self.hypotheses.append(h)

    def step(self, frame: ScanFrame) -> Step:
        """Move, verify and decide for one scan."""
        self.scan += 1
        self.front.predict(frame)
        u, q = self.front.increment
        points = frame.points()
        for h in self.hypotheses:
            h.filter.predict(u, q)
            self._track(h, points)
        proposals: list[Proposal] = []
        if self._searching() and self.scan - self._last_search >= SEARCH_EVERY:
            self._last_search = self.scan
            proposals = propose(self.places, frame, self.config.registration, self.stats)
            for p in proposals:
                self._add(p)
        self._prune()
        self.state = self._decide()
        self.stats[f"scans {self.state.value}"] += 1
        ranked = sorted(self.hypotheses, key=lambda h: (-h.trusted, -h.finds, h.misses))
        trusted = self._trusted()
        pose = (trusted.pose.copy() if self.state is State.LOCALIZED and trusted is not None
                else None)
        return Step(self.state, pose, [h.pose.copy() for h in ranked], proposals)

    # ---- hypotheses ------------------------------------------------------------------------

    def _start(self, pose: FloatArray, cov: FloatArray, finds: int) -> Hypothesis:
        return Hypothesis(PoseFilter(pose, cov, self.config.motion), finds, since=self.scan)

    def _track(self, h: Hypothesis, points: FloatArray) -> None:
        """Register the scan where ``h`` puts it; a fit within its gate corrects it."""
        place = self.places.nearest(h.pose) if len(points) >= MIN_POINTS else None
        if place is None:
            h.misses += 1
            h.scores.append(0.0)
            return
        reg = register(place.reference, points, relative(place.pose, h.pose))
        z = compose(place.pose, reg.pose)
        R = rotate_covariance(reg.covariance, place.pose[2])
        score = place.grid.score(points[np.hypot(points[:, 0], points[:, 1]) <= REACH],
                                 reg.pose)
        if (fits(reg, self.config.registration) and score >= KEEP_RATIO * h.usual
                and h.filter.mahalanobis2(z, R) <= CHI2_3DOF_99):
            h.filter.update(z, R)
            h.misses = 0
            h.fits += 1
            h.fitted.append(score)
            h.scores.append(score)
        else:
            h.misses += 1
            h.scores.append(0.0)

    def _add(self, p: Proposal) -> None:
        """A proposal is one more find for the hypothesis it agrees with, or a new one."""
        for h in self.hypotheses:
            d = relative(h.pose, p.pose)
            if math.hypot(d[0], d[1]) <= SAME_XY and abs(d[2]) <= SAME_THETA:
                h.finds += 1
                h.history.append(p.milestone)
                return
        cov = rotate_covariance(np.diag(np.square(PROPOSAL_SIGMA)), p.pose[2])
        h = self._start(p.pose, cov, 1)
        h.history.append(p.milestone)
        h.scores.append(p.score)
        h.fitted.append(p.score)
        self.hypotheses.append(h)

    def _prune(self) -> None:
        """Drop hypotheses that stopped fitting, merge ones that met, keep the best few."""
        keep: list[Hypothesis] = []
        for h in sorted(self.hypotheses, key=lambda h: (-h.trusted, -h.finds, h.misses)):
            if h.misses > (DEAD_RECKONING if h.trusted else DROP_AFTER):
                continue
            same = next((k for k in keep if _same(k.pose, h.pose)), None)
            if same is not None:
                same.finds += h.finds if not h.trusted else 0
                continue
            keep.append(h)
        self.hypotheses = keep[:MAX_HYPOTHESES]

    def _trusted(self) -> Hypothesis | None:
        return next((h for h in self.hypotheses if h.trusted), None)

    # ---- the decision ----------------------------------------------------------------------

    def _searching(self) -> bool:
        """Whether to look for the place: unless a trusted hypothesis fits."""
        t = self._trusted()
        return t is None or t.misses > 0

    def _decide(self) -> State:
        trusted = self._trusted()
        if trusted is not None and trusted.misses < LOST_AFTER:
            return State.LOCALIZED
        # Not localized (or lost): a hypothesis found often enough that fits now, with no
        # other about as well supported that fits too, is the place.
        fitting = [h for h in self.hypotheses if h.misses == 0 and h is not trusted]
        if not fitting:
            return State.SEARCHING if trusted is None else State.LOST
        best = max(fitting, key=lambda h: h.score)
        rivals = [h for h in fitting if h is not best and h.score >= RIVAL_RATIO * best.score]
        if best.finds < MIN_FINDS:
            return State.SEARCHING if trusted is None else State.LOST
        if rivals:
            return State.AMBIGUOUS
        # The others are dropped: while localized nothing proposes places, so none of them
        # could gain a find, and following them would cost a registration a scan each.
        best.trusted = True
        self.hypotheses = [best]
        self.stats["times localized"] += 1
        return State.LOCALIZED


def _same(a: FloatArray, b: FloatArray) -> bool:
    d = relative(a, b)
    return math.hypot(d[0], d[1]) <= SAME_XY and abs(d[2]) <= SAME_THETA
