"""Localization in a saved map without a starting pose: propose, verify, decide, track.

Every scan, each hypothesis of where the robot is (a pose filter of its own) moves by the
odometry increment (:mod:`vmp.frontend`) and is registered against the saved map
(:mod:`vmp.places`): a close fit within its filter's gate corrects it, a scan without one is a
miss. Until one hypothesis is trusted, the milestone signatures propose
places every few scans (:mod:`vmp.relocalization`), each search leaving out the places already
followed and the milestones searched from about here, so that search after search goes farther
down the signatures' list: a place that looks like the right one must not win only because the
right one was never looked at. A proposal, found in its milestone's submap, is moved to the
pose that explains the scan best in the whole map nearby (:meth:`Localizer._refined`).
Where the signatures propose nothing (no milestone near: the robot drives where the map was
seen from afar), the whole map is searched now and then, every heading, for a pose that
explains the scan clearly better than any other (:meth:`Localizer._anywhere`), as
Cartographer's global localization searches its submaps.

How well a scan fits a hypothesis is the mean likelihood of its points in the map at the
registered pose (:meth:`vmp.places.Places.score`: the branch-and-bound search's score, without
its grid's rounding). A scan fits when ICP fits closely,
within the hypothesis's gate, and it scores at least :data:`KEEP_RATIO` of what the hypothesis
usually scores (a robot carried to a look-alike corridor still registers against the old
one's walls, but its doors and ends no longer score). The robot is localized on the
hypothesis that fits now and scores best over the last :data:`WINDOW` scans, once it has
fitted :data:`MIN_FITS` scans and outlived :data:`MIN_SEARCHES` searches for other places,
while no other place followed explains the scans about as well: leaves unexplained (one
minus its score) less than :data:`RIVAL_FACTOR` times the best's share plus
:data:`RIVAL_MARGIN` (then it is ambiguous:
in a corridor seen only to 8 m, or one whose pilasters all look alike, the right place cannot
be told from the others until the robot sees something that tells them apart). In the
simulated office (scored in the submaps' grids, with their rounding) the right place scores
0.998 (median; 0.98 at the tenth percentile), wrong
ones that ICP still fits 0.67 (0.84 at the ninetieth), but other stretches of corridor seen
only to 8 m up to 0.976 over twenty scans: a ratio of scores cannot tell them apart, the
share of points left unexplained can (0.001 against 0.024). The signatures propose only
places with a milestone, and the mapper records none where a view matches one recorded
already (a corridor of pilasters keeps milestones only near its ends), so before a place is
declared the scan is also searched along the saved path far from it (:meth:`_elsewhere`).
That search matches the last scans the place explains, carried into this scan's frame, not
this scan alone: along aisles of alike bays many poses fit one scan whose scans before tell
them apart, and a search that finds them one by one runs out of its tries.

It stays localized while the scans fit; after :data:`LOST_AFTER` misses in a row it is lost:
the hypothesis keeps moving with odometry (the robot may just be looking into a room the map
never saw) while the search looks for the place anew (the robot may have been carried
elsewhere, the kidnapped robot), and the map is searched about where scan odometry has carried
the place lost, in a window that grows with the distance driven (:meth:`Localizer._reckon`).
The lost place takes over again once it fits
:data:`MIN_FITS` scans in a row, unless a place found meanwhile explains those scans clearly
better (the robot was there, and a look-alike room elsewhere is no reason to doubt it); a
place found otherwise takes over as above. Its filter, sure of the heading it dead-reckoned,
is moved to a registration outside its gate that explains the scan clearly better
(:meth:`Localizer._restart`).

Where places score alike by their end points (the simulated warehouse's rack bays along an
aisle all score 1.000), the saved map's views may tell them apart (:mod:`vmp.views`: how many
of the live beams the stored scans taken near a place contradict, seen from there). Each
place followed keeps its views beside its scores while it is compared with others; among the
best and its rivals, the one whose views agree clearly better with the scans than every
other's is the place (:meth:`Localizer._told_apart`), and a look-alike the search near it
finds that only the views tell apart is followed, to be compared so too (where the views
agree with the best place, one the scans before do not tell apart at all is followed too).
One the search along the saved path finds that the views of the scans before tell apart is
not: followed, it would be compared over the scans both have views for, and the bays of an
aisle read alike once the robot has moved on (:meth:`Localizer._elsewhere`). The views see
what registration against the map's wall bands leaves free, where along an aisle or a
corridor the place is: each place whose view is taken is also seen from offsets along the
direction its filter is least sure of, and placed where they contradict the scan least
(:meth:`Localizer._placed_by_views`); drifted a decimetre or two along, the right bay's
views contradict the scans as much as a look-alike's.

A robot carried to a look-alike nearby (a rack bay further along the aisle) may go on fitting
the old place, only less well. The place trusted is doubted while it explains the scans clearly
worse than when it was declared (by the measure that tells a place clearly better than
another): the poses within :data:`ALIAS_WINDOW` of it, and then the saved path, are searched
for one that explains the scan clearly better, and such a pose is followed beside it for
:data:`WINDOW` scans; if it explains those scans clearly better, the place trusted gives way and
the robot is lost (and then localized, or ambiguous among bays alike, as above). Only to a
place the robot may have come to: near it, or one the scans before it was followed stop
fitting (a kidnap breaks them); one farther off that explains them all the way back is a
look-alike along the path driven, where the map may just be fuller (:func:`_reachable`). After
:data:`DOUBT_SEARCHES` searches that find nothing, the place explains what the map holds there
(a room the map never saw) and is doubted again only after a further fall.

A robot carried to a look-alike bay farther off may fit the old place as well as ever by its
end points. A place declared where its views agreed with the scans is watched by them: when
they contradict the scans clearly more than then (:func:`_seen_off`), the poses near it and
along the saved path that explain the scan as well are searched, those whose views agree
clearly better are followed, and one that explains the scans since as well with views that
agree clearly better takes over as above (:meth:`Localizer._view_doubt`), the scans before it
was followed forgotten. Where the searches find none, the views see what the map does not hold:
the place is no longer watched by them.

Tracking a saved map differs from mapping in two ways that matter. The map is assembled from
many scans, its walls bands a few centimetres thick, where ICP matches only points whose
partner lies on a clear line: a registration fits when most of the scan lies near a map point
(:meth:`vmp.places.Place.fits`). And the hypotheses move by scan odometry, as the mapper's
filter does: a registration against such a map places one scan to a centimetre or two, and
scan after scan those errors do not average out unless the motion between them is known
better still. Once trusted, a place is registered against the map every decimetre or five
degrees of travel, scan odometry carrying it in between; every scan is still scored there.
A robot localized that stands still and sees what it saw is left where it is: its scans are
not registered, scored or searched from again (:meth:`Localizer._still`).
"""

from __future__ import annotations

import math
import statistics
from collections import Counter, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from vmp.branch_bound import Match, first_match, search, search_points
from vmp.config import MappingConfig
from vmp.frontend import NEW_VIEW_XY, FrontEnd, new_view
from vmp.fusion import CHI2_3DOF_99, PoseFilter
from vmp.places import Places
from vmp.registration import MIN_POINTS, register
from vmp.relocalization import Proposal, propose
from vmp.types import (
    FloatArray,
    ScanFrame,
    compose,
    inverse,
    relative,
    rotate_covariance,
    transform_points,
    widest_direction,
    widest_variance,
)

__all__ = ["Hypothesis", "Localizer", "State"]

MIN_SEARCHES = 3  # searches for other places a hypothesis must outlive to be trusted ...
MIN_FITS = 5  # ... and scans it must have fitted
SEARCH_EVERY = 2  # scans between searches while not localized
LOST_AFTER = 5  # misses in a row after which the robot is lost
MIN_SCORE = 0.7  # the least mean score over the window of a place to be declared
DROP_AFTER = 3  # misses in a row after which an untrusted hypothesis is dropped
DEAD_RECKONING = 100  # misses in a row after which a trusted one is dropped too
RETRY_XY = 0.5  # a milestone searched is searched again once the robot moved this far (m) ...
RETRY_THETA = math.radians(10.0)  # ... or turned this much
SAME_XY = 0.3  # a proposal this near a hypothesis (m) ...
SAME_THETA = math.radians(5.0)  # ... and turned this little agrees with it
# Searches made while the place trusted is doubted before its reference score is lowered to
# what it scores now.
DOUBT_SEARCHES = 3
# The most places followed at once (the lowest ranked dropped): along the simulated
# warehouse's aisles a dozen bays score alike by their end points, and each must stay followed
# until the views tell them apart.
MAX_HYPOTHESES = 16
WINDOW = 20  # scans over which hypotheses are compared
KEEP_RATIO = 0.8  # a scan scoring less than this share of a hypothesis's usual is a miss
# A place is a rival of the best when it leaves fewer than this many times the share of the
# scans' points the best leaves unexplained (1 - score), plus this share. A place followed
# that is no rival is left out of the searches for look-alikes (:func:`_left_behind`).
RIVAL_FACTOR = 2.0
RIVAL_MARGIN = 0.01
# The same margin for scores read from a branch-and-bound search grid (the searches for
# look-alikes), wider: its 0.1 m cells round a point's score by up to a third, and a scan's by
# a tenth (at 0.01 the simulated corridor's search along the path misses the right stretch).
GRID_MARGIN = 0.02
# Live points registered and scored: within this range (m), a submap's reach
# (vmp.places.GRID_RADIUS); with every point, fewer of ACES's second half's scans localize.
REACH = 20.0
# Before a place is declared, the poses this far around it (m, rad) are searched for one that
# explains the scan about as well (a pilaster 5 m along a corridor, a rack bay 2.5 m along an
# aisle), leaving out those within ALIAS_APART of it.
ALIAS_WINDOW = 6.0
ALIAS_TURN = math.radians(5.0)
ALIAS_APART = (0.5, math.radians(5.0))
# Look-alikes of a place a search may find one after another, each told apart by the scans
# before (:meth:`Localizer._told_by_the_past`), before the place is called ambiguous anyway.
MAX_ALIKE = 8
# The search along the saved path for look-alikes of a place (:meth:`Localizer._elsewhere`)
# matches the last scans it explains in a row, this many at most, carried into this scan's
# frame by scan odometry (:meth:`Localizer._searched_with`): along the simulated warehouse's
# aisles many poses fit this scan alone but not the scans before. The search nearby
# (:meth:`Localizer._aliased`) matches this scan alone: where it fits many poses a few
# decimetres apart (a corridor), running out of tries on them keeps a look-alike undeclared.
SEARCH_SCANS = 10
# Around each sample of the saved path the scan is searched this far either way (m, rad):
# the samples lie a metre apart, and the robot at a look-alike stands to the path about as
# it does at the place.
PATH_WINDOW_XY = 0.6
PATH_WINDOW_THETA = math.radians(10.0)
# A place's views (:mod:`vmp.views`) agree clearly better with the scans than another's when
# the other's contradict more than VIEW_FACTOR times the share of beams the first's do, plus
# VIEW_MARGIN, and the difference is VIEW_Z standard deviations or more, over MIN_VIEWS scans
# at least that both have a view for (:func:`_seen_clearly_better`).
VIEW_FACTOR = 1.5
VIEW_MARGIN = 0.01
# Views that contradict more than this share of the beams at the better place tell nothing
# apart: the right places' views contradict 0-1.2 % in the simulated worlds, but 9-34 % on
# ACES (people, a path a few decimetres aside).
VIEW_MOST = 0.05
VIEW_Z = 3.0
MIN_VIEWS = 5
# A place a search finds is judged on the scans before it, carried back along scan odometry,
# where a wall seen at a grazing angle from a pose a little off contradicts more beams: told
# apart by views so at this margin only (at 0.01, the searches tell so many of the simulated
# corridor's look-alikes apart by their views that one facing the other way is declared).
FOUND_VIEW_MARGIN = 0.03
# A place is placed along the direction its filter is least sure of by its views from
# offsets this far apart (m: half a view's agreement, vmp.views.AGREE) ...
PLACE_STEP = 0.05
PLACE_SIGMAS = 2.0  # ... out to this many of its standard deviations either way ...
PLACE_MOST = 6  # ... and this many steps at most (:meth:`Localizer._placed_by_views`).
PLACE_FREE = 100.0  # standard deviation (m, rad) of what such a placement does not measure
# A proposal, found in its milestone's submap, is moved to the best pose within this far
# either way (m, rad) in the whole map (:meth:`Localizer._refined`).
REFINE_XY = 1.0
REFINE_THETA = math.radians(5.0)
# While the signatures propose no place, the whole map is searched every this many scans at
# most, once the robot has moved or turned as much as before a milestone is searched again
# (:meth:`Localizer._anywhere`; a search costs about 0.15 s on ACES's map, the signatures'
# a few milliseconds), for a pose that explains the scan clearly better than every other
# farther than ANYWHERE_APART (m, rad) from it (the shoulders of its own peak excluded).
ANYWHERE_EVERY = 10
ANYWHERE_APART = (1.0, math.radians(20.0))
# Once lost, the robot is looked for where scan odometry has carried the place lost: within
# RECKON_XY[0] plus RECKON_XY[1] times the distance driven since (m) either way, and
# RECKON_THETA likewise (rad, per metre), at most RECKON_MOST_THETA; searched as the whole
# map is (every ANYWHERE_EVERY scans at most, once moved), until the window would exceed
# RECKON_MOST_XY: scan odometry against one go's poses (every 25th scan of ACES, fr079 and
# the Intel part) is off by up to 1.1 m and 9 deg after 10 m, 3.6 m and 20 deg after 40 m
# (95th percentile).
RECKON_XY = (1.0, 0.1)
RECKON_THETA = (math.radians(10.0), math.radians(0.3))
RECKON_MOST_XY = 8.0
RECKON_MOST_THETA = math.radians(30.0)
# How well a proposal's pose is known when a hypothesis starts from it (m, m, rad).
PROPOSAL_SIGMA = (0.1, 0.1, math.radians(2.0))


class State(Enum):
    """What the localizer knows after a scan."""

    SEARCHING = "searching"  # no place found yet, or several that fit as well
    AMBIGUOUS = "ambiguous"  # more than one place fits and was found about as often
    LOCALIZED = "localized"  # one place, trusted, and the scan fits there
    LOST = "lost"  # was localized, the scans stopped fitting


View = tuple[int, int]  # live beams a place's view contradicts, and those it knows
NO_VIEW: View = (0, 0)


@dataclass(eq=False)  # one place followed: compared by identity
class Hypothesis:
    """A place the robot may be: its filter, how it has fitted, what it has outlived."""

    filter: PoseFilter
    searches: int = 0  # searches for other places since it was proposed
    misses: int = 0  # scans in a row that did not fit
    fits: int = 0  # scans that fitted
    streak: int = 0  # scans in a row that fitted (since the last miss)
    trusted: bool = False  # the localizer has declared it, and it has not been lost since
    declared: bool = False  # the localizer has declared it once (it may dead-reckon)
    scores: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW))  # 0: a miss
    fitted: deque[float] = field(default_factory=lambda: deque(maxlen=2 * WINDOW))
    registered_at: FloatArray | None = None  # its pose at the last registration
    checked_at: FloatArray | None = None  # odometry pose when the path was searched for it
    alike: bool = False  # whether that search found a look-alike
    # Odometry pose when the whole map was searched for a pose explaining the scan clearly
    # better, before it was to be declared (:meth:`Localizer._bettered`).
    bettered_at: FloatArray | None = None
    # How well the place explained the scans when it was declared (its mean score then), and
    # the searches made since while it explained them less well (:meth:`Localizer._doubted`).
    reference_score: float = 0.0
    doubts: int = 0
    # Its views over the scans before it was declared, where they vouched for it (they
    # contradicted at most VIEW_MOST of the beams); empty otherwise, or once searches made
    # while they contradicted the scans found no place they agree with better
    # (:meth:`Localizer._view_doubt`).
    declared_views: list[View] = field(default_factory=list)
    view_doubts: int = 0  # those searches that found no place
    # Its scores on the scans before it was proposed, oldest first, the robot carried back
    # along their increments (:meth:`Localizer._past`): compared with the others over them too.
    past: list[float] = field(default_factory=list)
    # Beside each score, the live beams the saved map's view from the place contradicts and
    # those it knows (:class:`vmp.views.SavedViews`; (0, 0): no view, or not looked at).
    views: deque[View] = field(default_factory=lambda: deque(maxlen=WINDOW))
    past_views: list[View] = field(default_factory=list)

    @property
    def history(self) -> list[float]:
        """Its scores over the last :data:`WINDOW` scans, those before it was proposed
        included (a miss counts 0)."""
        return (self.past + list(self.scores))[-WINDOW:]

    @property
    def view_history(self) -> list[View]:
        """Its views over the scans of :attr:`history`."""
        return (self.past_views + list(self.views))[-WINDOW:]

    def record(self, score: float, view: View) -> None:
        """One more scan's score (0: a miss) and view."""
        self.scores.append(score)
        self.views.append(view)

    @property
    def known_fits(self) -> int:
        """The scans it fitted, those before it was proposed included."""
        return self.fits + sum(score > 0.0 for score in self.past[-WINDOW:])

    @property
    def pose(self) -> FloatArray:
        return self.filter.pose

    @property
    def score(self) -> float:
        """Mean score over the last :data:`WINDOW` scans (a miss counts 0)."""
        # statistics, not NumPy: on 20 numbers a NumPy call is mostly its overhead, and
        # this is asked for several times a scan for every place followed.
        return statistics.fmean(self.scores) if self.scores else 0.0

    @property
    def usual(self) -> float:
        """The median score of its recent fitting scans (0 before the first)."""
        return statistics.median(self.fitted) if self.fitted else 0.0


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
        # The hypotheses move as the mapper's filter does: by the wheels refined by scan
        # odometry. Moved by the wheels alone (their registrations against the map doing what
        # scan odometry would), each scan's registration against the map's thick walls pulls
        # its own way: tracking the Intel part's second half scores 0.03 m so, 0.022 m with
        # scan odometry (0.014 m mapped). Its ICP stops where its steps cycle (else 126 of
        # 1,535 on ACES's tracked half run to the cap, 27 % of that ICP's time) or no longer
        # change the fit.
        self.front = FrontEnd(self.config, filtered=False, stops_early=True,
                              by_all_points=False)
        # The place trusted is registered against the map once it has moved or turned as far
        # as scan odometry goes before it takes a new keyframe (0.3 m or 10 deg by default);
        # in between, scan odometry carries it and each scan is scored where it is
        # predicted, so that a kidnap is still noticed. Within a keyframe's span scan
        # odometry registers each scan against that one keyframe, so its error does not
        # build up scan by scan, and registrations of nearly the same view against the same
        # map share the map's own local error. (Every 0.1 m or 5 deg, registering against the
        # map and correcting the filter would take a quarter of ACES's tracked time: 190 us a
        # registration against scan odometry's 90.) Without scan odometry the wheels alone
        # carry it: it is registered whenever it moved (:func:`vmp.frontend.new_view`).
        keyframes = self.config.scan_odometry
        self._track_every: tuple[float, ...] = (
            (keyframes.keyframe_distance, keyframes.keyframe_turn) if keyframes.enabled
            else ())
        self.stats: Counter[str] = Counter()
        self.hypotheses: list[Hypothesis] = []
        self.scan = -1
        self._points = np.zeros((0, 2))  # this scan's points ...
        self._ranges = np.zeros(0)  # ... its ranges ...
        self._within = np.zeros((0, 2))  # ... and those within REACH
        self._last_search = -SEARCH_EVERY
        # The last search of the whole map: its scan, and the robot's pose by odometry then
        # (searched again only from elsewhere, as a milestone is).
        self._last_anywhere = -ANYWHERE_EVERY
        self._anywhere_at: FloatArray | None = None
        # Where scan odometry has carried the place lost since the robot was lost, and how
        # far it drove since (None once localized again, or too far to say); the last search
        # there, as the whole map's.
        self._reckoned: FloatArray | None = None
        self._driven = 0.0
        self._last_reckon = -ANYWHERE_EVERY
        self._reckon_at: FloatArray | None = None
        self.state = State.SEARCHING
        self._lost = False  # localized once, and the scans stopped fitting
        # The robot's pose by odometry alone (its own frame), and where it was when each
        # milestone was last searched: searched again only from elsewhere.
        self._odometry = np.zeros(3)
        self._tried: dict[int, FloatArray] = {}
        # The last scans' points within REACH, each with the increment that brought the robot
        # to it: where a place proposed now would have put them (:meth:`_past`).
        self._recent: deque[tuple[FloatArray, FloatArray, FloatArray]] = deque(maxlen=WINDOW)
        self._last_frame: ScanFrame | None = None  # the last scan not left out as still
        if initial_pose is not None:  # one more place to follow, judged like the others
            self.hypotheses.append(self._start(
                np.asarray(initial_pose, dtype=np.float64),
                np.diag([0.3**2, 0.3**2, math.radians(10.0) ** 2])))

    def step(self, frame: ScanFrame) -> Step:
        """Move, verify and decide for one scan."""
        self.scan += 1
        if self._still(frame):
            # Nothing to move, verify or search: the last scan's answer stands.
            self.front.hold(frame)
            self.stats["scans standing still, left out"] += 1
            self.stats[f"scans {self.state.value}"] += 1
            pose = self.hypotheses[0].pose.copy()
            return Step(self.state, pose, [pose.copy()], [])
        self._last_frame = frame
        points = self._points = frame.points()
        self._within = points[np.hypot(points[:, 0], points[:, 1]) <= REACH]
        self.front.predict(frame, points)
        u, q = self.front.increment
        self._odometry = compose(self._odometry, u)
        if self._reckoned is not None:
            self._reckoned = compose(self._reckoned, u)
            self._driven += math.hypot(u[0], u[1])
        self._ranges = frame.ranges
        self._recent.append((self._within, u, frame.ranges))
        fitted = []
        for h in self.hypotheses:
            h.filter.predict(u, q)
            score = self._track(h)
            if score is not None:
                fitted.append((h, score))
        self._record(fitted)
        proposals: list[Proposal] = []
        trusted = self._trusted()
        if self.scan - self._last_search >= SEARCH_EVERY:
            if trusted is None:
                self._last_search = self.scan
                proposals = self._search(frame)
            elif self._doubted(trusted):
                self._last_search = self.scan
                self._challenge(trusted)
            elif _seen_off(trusted) and len(self.hypotheses) == 1:
                self._last_search = self.scan
                self._view_doubt(trusted)
        self._prune()
        self.state = self._decide()
        self.stats[f"scans {self.state.value}"] += 1
        ranked = sorted(self.hypotheses, key=lambda h: (-h.trusted, -h.score))
        trusted = self._trusted()
        pose = (trusted.pose.copy() if self.state is State.LOCALIZED and trusted is not None
                else None)
        return Step(self.state, pose, [h.pose.copy() for h in ranked], proposals)

    def _still(self, frame: ScanFrame) -> bool:
        """Whether the robot, localized on the one place followed, stands where it stood at
        the last scan not left out and sees what it saw then: its wheels moved less than a new
        view (:func:`vmp.frontend.new_view`) and most beams read the same
        (:func:`_same_view`). Such a scan says nothing new: the mapper does not match it
        either. (ACES's second half stands still on 41 % of its scans, and tracking such a
        scan would cost 239 us: half of it scan odometry finding no motion, the rest scoring
        the same view again and searching anew for a better place from where the search
        before found none.) A robot carried
        off sees something else, even when its wheels stand still."""
        last = self._last_frame
        if (self.state is not State.LOCALIZED or len(self.hypotheses) != 1
                or self.hypotheses[0].misses or last is None
                or frame.odom is None or last.odom is None
                or frame.ranges.shape != last.ranges.shape
                or new_view(last.odom, frame.odom)):
            return False
        return _same_view(last.ranges, frame.ranges)

    def _search(self, frame: ScanFrame) -> list[Proposal]:
        """Places proposed by the signatures, followed from now on; where they propose none,
        now and then the place found in the whole map (:meth:`_anywhere`)."""
        for h in self.hypotheses:
            h.searches += 1
        proposals, searched = propose(self.places, frame, self.config.registration,
                                      self.stats, [h.pose for h in self.hypotheses],
                                      tried=self._tried_here())
        self._tried.update((mid, self._odometry.copy()) for mid in searched)
        for p in proposals:
            self._follow(self._refined(p.pose))
        if not proposals and self._due(self._last_anywhere, self._anywhere_at):
            self._last_anywhere = self.scan
            self._anywhere_at = self._odometry.copy()
            self._anywhere()
        if self._reckoned is not None and self._due(self._last_reckon, self._reckon_at):
            self._last_reckon = self.scan
            self._reckon_at = self._odometry.copy()
            self._reckon()
        return proposals

    def _due(self, last: int, at: FloatArray | None) -> bool:
        """Whether a search last made at scan ``last``, from ``at`` by odometry (None: from
        nowhere yet), is due again: :data:`ANYWHERE_EVERY` scans on, and from a new view."""
        return self.scan - last >= ANYWHERE_EVERY and (at is None or self._moved_since(at))

    def _anywhere(self) -> None:
        """Follow the pose that explains this scan best in the whole map
        (:meth:`vmp.places.Places.everywhere`), where it explains it clearly better than
        every place followed and every pose farther than :data:`ANYWHERE_APART` from it (a
        look-alike anywhere in the map). The signatures propose only places with a
        milestone near: of the scans of ACES's second half its first half's map explains
        but the signatures do not localize, 73 of 115 (sampled) have none within the
        search's 2 m, the nearest 3.6 m off at the median; searched in the whole map, 24 of
        81 are found so, none wrong."""
        live = search_points(self._points)
        if len(live) < MIN_POINTS:
            return
        # Only a pose that explains the scan clearly better than every place followed is
        # followed beside them: the search prunes below that, and is not run where nothing
        # could be (a place followed explains the scan fully): ACES's second half is tracked
        # in 38.9 s so rather than 46.6 (its slowest scan while searching 412 ms rather than
        # 690), the Intel part's in 14.1 rather than 18.5, the same share localized.
        self._follow_clear_best(live, lambda least, exclude: self.places.everywhere(
            live, least, exclude), "of the whole map", "in the whole map")

    def _reckon(self) -> None:
        """Follow the pose that explains this scan clearly better than every place followed
        and every other pose farther than :data:`ANYWHERE_APART` from it, within the window
        about where scan odometry has carried the place lost (:data:`RECKON_XY`,
        :data:`RECKON_THETA`). The signatures propose only places with a milestone near,
        and while they propose some the whole map is not searched: coming back from rooms
        the first part of ACES never saw, the robot would go unlocalized for a hundred scans
        where the map explains them (scans 1,105-1,209 of its second half, the signatures
        proposing look-alikes 18-35 m off), though the pose best in the whole map is the
        right one, and the only one, from scan 1,183 on. A robot carried off is still found
        by the signatures; found here, a place is judged as any other."""
        xy = RECKON_XY[0] + RECKON_XY[1] * self._driven
        if xy > RECKON_MOST_XY:
            self._reckoned = None  # driven too far to say where
            return
        theta = min(RECKON_THETA[0] + RECKON_THETA[1] * self._driven, RECKON_MOST_THETA)
        live = search_points(self._points)
        if len(live) < MIN_POINTS:
            return
        center, grid = self._reckoned, self.places.grid
        self._follow_clear_best(live, lambda least, exclude: search(
            grid, live, center, xy, theta, least, exclude),
            "where the robot dead-reckons", "where the robot dead-reckons")

    def _follow_clear_best(self, live: FloatArray,
                           find: Callable[[float, tuple | None], Match | None],
                           searched: str, found: str) -> None:
        """Follow the pose ``find(least, exclude)`` returns for the points ``live``, where it
        explains them clearly better than every place followed and every pose farther than
        :data:`ANYWHERE_APART` from it (a look-alike elsewhere in the window searched);
        counted as searches ``searched`` and places ``found``."""
        grid = self.places.grid
        least = max([MIN_SCORE] + [_least_clearly_better(grid.score(live, h.pose))
                                   for h in self.hypotheses])
        if least >= 1.0:
            return
        self.stats[f"searches {searched}"] += 1
        best, other = _best_and_alike(find, least)
        if best is None or (other is not None and _as_well(other.score, best.score,
                                                             GRID_MARGIN)):
            return
        self.stats[f"places found {found}"] += 1
        self._follow(self._registered(best.pose))

    def _refined(self, pose: FloatArray) -> FloatArray:
        """The best pose of this scan within :data:`REFINE_XY` and :data:`REFINE_THETA` of
        ``pose`` (a proposal) in the whole map, registered there where that fits; ``pose``
        when none scores better. A milestone's submap holds only what was seen near the
        milestone, and the pose best there may sit off in the whole map, where ICP holds it
        on its own minimum: the simulated warehouse's kidnap of seed 119 is proposed 0.78 m
        along the aisle from the right bay, scoring 0.946 where the right pose scores 1.000,
        and ICP does not find the right pose from there."""
        live = search_points(self._points)
        if len(live) < MIN_POINTS:
            return pose
        grid = self.places.grid
        here = grid.score(live, pose)
        better = search(grid, live, pose, REFINE_XY, REFINE_THETA, here)
        if better is None or better.score <= here:
            return pose
        self.stats["proposals moved in the whole map"] += 1
        return self._registered(better.pose)

    def _challenge(self, trusted: Hypothesis) -> None:
        """Search around the place trusted, doubted, for a pose that explains the scan clearly
        better (a rack bay further along the aisle), and follow it. (The signatures' search
        would find places anywhere, but costs about 0.15 s, and real logs doubt their place
        now and then where the map is thin: it would cut tracking on ACES's second half to a
        third of its speed.)"""
        self.stats["searches while doubted"] += 1
        trusted.doubts += 1
        if trusted.doubts >= DOUBT_SEARCHES:
            # Nothing found explains the scans better: the place explains what the map holds
            # here (a room it never saw), and only a further fall is doubted.
            trusted.reference_score = trusted.score
            trusted.doubts = 0
        live = search_points(self._points)
        found = self._near(trusted, _least_clearly_better, live)
        if found is not None and _clearly_better(found[1], found[2], GRID_MARGIN):
            self._follow(found[0])
            return
        if trusted.doubts:
            return
        # A robot carried farther than the window (along an aisle, 14.6 m back in the
        # simulated warehouse) still fits the old place at 0.85: the saved path is searched
        # too, at the last search of the doubt (the real logs doubt their place now and then
        # where the map is thin; searched at every one, tracking on ACES slows by a fifth).
        far = self._along_path(trusted.pose, _least_clearly_better, live, [trusted.pose])
        if far is not None:
            self.stats["places found along the path while doubted"] += 1
            self._follow(far.pose)

    def _view_doubt(self, trusted: Hypothesis) -> None:
        """Search for places that explain this scan about as well as the place trusted,
        whose views contradict the scans (:func:`_seen_off`), near it and along the saved
        path, and follow them: one whose views agree clearly better takes its place
        (:meth:`_outseen`). After :data:`DOUBT_SEARCHES` searches that find none, the place is
        no longer watched by its views: they see what the map does not hold here.

        A robot carried to a look-alike bay still fits the old place by its end points (in
        the simulated warehouse's kidnaps of seeds 123 and 134, carried 15.6 and 22.6 m, at
        0.95-1.00 for 36 scans), but its views, contradicting 0-1 of 181 beams before the
        kidnap, contradict 9-17 from the first scan after. Losing the place on its views alone
        would lose it on real logs too, where views vouch only in a good spot and contradict
        7-54 % of the beams a few metres on: only a place found gives way."""
        self.stats["searches while the views doubted"] += 1
        live = search_points(self._points)
        known = [trusted.pose]
        recent = _last_views(trusted)
        found = 0
        for pose in self._alike(trusted, live, known):
            if found >= MAX_HYPOTHESES - 1:  # with the place trusted, as many as are followed
                break
            pose = self._registered(pose)
            view = self._views([self._ranges], [pose])
            if view[0][1] and _views_apart(view, recent, VIEW_MARGIN):
                self._follow(pose)
                found += 1
        if found:
            self.stats["places found while the views doubted"] += found
            return
        trusted.view_doubts += 1
        if trusted.view_doubts >= DOUBT_SEARCHES:
            trusted.declared_views = []

    def _alike(self, h: Hypothesis, live: FloatArray, known: list[FloatArray]
               ) -> Iterator[FloatArray]:
        """The poses near ``h`` (:meth:`_near`, each found added to ``known``),
        :data:`MAX_ALIKE` at most, then along the saved path (:meth:`_all_along_path`), where
        the points ``live`` explain about as well as at ``h``, :data:`MAX_ALIKE` times
        :data:`MAX_HYPOTHESES` in all at most. (Each search near ``h`` leaves out every pose
        found before it, and where the map explains the scan about as well all around, as in
        an open hall, they would run on: on ACES's second half 128 of them, 47 ms each, take
        one scan 6.2 s; the search along the path goes on from where it stopped.)"""
        tries = 0
        while tries < MAX_ALIKE:
            near = self._near(h, _least_as_well, live, known)
            if near is None or not _as_well(near[1], near[2], GRID_MARGIN):
                break
            known.append(near[0])
            tries += 1
            yield near[0]
        for far in self._all_along_path(h.pose, _least_as_well, live, known):
            if tries >= MAX_ALIKE * MAX_HYPOTHESES:
                return
            tries += 1
            yield far.pose

    def _registered(self, pose: FloatArray) -> FloatArray:
        """``pose`` registered against the whole map, where that fits; else ``pose``."""
        reg = register(self.places.reference, self._within, pose, corners=False, stops_early=True)
        return reg.pose if self.places.fits(reg, self._within, self.config.registration) else pose

    # ---- hypotheses ------------------------------------------------------------------------

    def _start(self, pose: FloatArray, cov: FloatArray) -> Hypothesis:
        return Hypothesis(PoseFilter(pose, cov, self.config.motion))

    def _track(self, h: Hypothesis) -> float | None:
        """Register the scan where ``h`` puts it; a close fit within its gate corrects it,
        a scan that scores less than usual there is a miss (recorded). The score of a scan
        that fits, to be recorded with its view (:meth:`_record`); None for a miss."""
        places, near = self.places, self._within
        if len(near) < MIN_POINTS or len(places.points) < MIN_POINTS:  # nothing to match
            h.misses += 1
            h.streak = 0
            h.record(0.0, NO_VIEW)
            return None
        update = False
        # A place trusted is registered once a keyframe's span (``_track_every``); one
        # followed, whenever the robot does not stand still.
        every = self._track_every if h.trusted else ()
        if new_view(h.registered_at, h.pose, *every):
            h.registered_at = h.pose.copy()
            # Lines only: in a map assembled from many scans and thinned to 5 cm, the walls
            # are bands, and three quarters of the Intel part's submap points (84 % on ACES)
            # have no clear line through their neighbours. The corner pass, meant for posts
            # and corners along an aisle, would match those band points point to point (on
            # 10,137 of ACES's 11,567 registrations); the direction lines leave free stays the
            # filter's, carried by scan odometry.
            # Stopped where its steps cycle (against a saved map's wall bands a quarter of
            # them would run to the cap: vmp.icp_kernel.CYCLE) or no longer change the fit
            # (vmp.icp_kernel.run_icp's ``settle``). Mapping's ICP runs on:
            # which pose of a cycle it ends on moves the Intel part's relation error between
            # 0.017 and 0.021 m.
            reg = register(places.reference, near, h.pose, corners=False, stops_early=True)
            if places.fits(reg, near, self.config.registration):
                update = h.filter.mahalanobis2(reg.pose, reg.covariance) <= CHI2_3DOF_99
                if (not update and h.declared
                        and _clearly_better(places.score(near, reg.pose),
                                            places.score(near, h.pose))):
                    self._restart(h, reg.pose)
        # Scored where the scan lands: registered, or predicted when ICP did not fit (part
        # of the view may lie outside the map, a room it never saw) or was not run.
        score = places.score(near, reg.pose if update else h.pose)
        if score < KEEP_RATIO * h.usual:
            h.misses += 1
            h.streak = 0
            h.record(0.0, NO_VIEW)
            return None
        if update:
            h.filter.update(reg.pose, reg.covariance)
        h.misses = 0
        h.fits += 1
        h.streak += 1
        h.fitted.append(score)
        return score

    def _restart(self, h: Hypothesis, pose: FloatArray) -> None:
        """Move ``h``, a place declared, to ``pose``, known as well as a place proposed: its
        filter is sure of a pose the scan fits clearly worse. A place dead-reckoned through
        scans that did not fit comes out of them as sure of its heading as it went in (within
        a degree), and a registration to the right pose may lie outside its gate scan after
        scan: on the Intel part's cut at 0.45 the place lost fits again 4 deg off, scoring
        0.75-0.81 where the registration scores 0.93-1.000, for 60 scans, and unmoved it
        would not resume. A place trusted drifts so too, its scan odometry surer than it
        should be (on the Intel part's second half 0.27 m off, moved to 0.14; 0.16 m, moved
        to 0.02). Only a place declared, where the robot was: moved so, a place proposed that
        is not the right one would fit its look-alike clearly better than its rivals do
        (fr079's cut at 0.45: 12 m off, declared). One that only fits as well, as the next
        pilaster of a corridor does, stays."""
        h.filter = PoseFilter(pose, _proposal_covariance(pose), self.config.motion)
        self.stats["places moved where the scan fits clearly better, outside their gate"] += 1

    def _record(self, fitted: list[tuple[Hypothesis, float]]) -> None:
        """Record the scores of the places ``fitted`` this scan, each with its view (one call
        for all). A place tracked alone is compared with none: its view is not looked at,
        unless it was declared where its views vouched for it (:func:`_seen_off`)."""
        if (len(fitted) == 1 and fitted[0][0].trusted and len(self.hypotheses) == 1
                and not fitted[0][0].declared_views):
            fitted[0][0].record(fitted[0][1], NO_VIEW)
            return
        # Each place's view at every offset of its own along its least sure direction
        # (:meth:`_placed_by_views`), all in one call.
        ways = [_least_sure(h) for h, _ in fitted]
        poses = [h.pose + offset * along
                 for (h, _), (along, offsets) in zip(fitted, ways, strict=True)
                 for offset in offsets]
        views = self._views([self._ranges] * len(poses), poses)
        first = 0
        for (h, score), (along, offsets) in zip(fitted, ways, strict=True):
            mine = views[first:first + len(offsets)]
            first += len(offsets)
            h.record(score, self._placed_by_views(h, along, offsets, mine))

    def _placed_by_views(self, h: Hypothesis, along: FloatArray, offsets: FloatArray,
                         views: list[View]) -> View:
        """Correct ``h`` along ``along`` (its least sure direction) where its views from
        ``offsets`` along it contradict the scan least, and its view from there.

        Against a saved map's wall bands, registration leaves the direction along an aisle or
        a corridor free, and scan odometry carries the place along it, drifting: the right
        place of the simulated warehouse's kidnap of seed 102 drifts from 0.08 to 0.20 m off
        along its aisle over 50 scans, its views then contradicting 2-4 % of the beams where
        they contradicted none, as many as a look-alike's (declared after 61 scans unplaced,
        after 26 placed so). The views see along the aisle (a beam stopped by a rack's end,
        or passing it): the offsets whose views contradict about as few beams as the fewest (within
        :data:`VIEW_Z` standard deviations of a count) are where the place is, as sure as half
        their spread (:data:`PLACE_STEP` at least). Only where they are one stretch, not every
        offset, and the fewest is at most :data:`VIEW_MOST` of the beams known: on the real
        logs' right places the views contradict 9-34 % (people, a path a little aside), and
        they place nothing there."""
        here = views[len(offsets) // 2]
        if len(offsets) == 1 or not all(known for _, known in views):
            return here
        wrong = np.array([w for w, _ in views])
        least = int(wrong.min())
        if least > VIEW_MOST * here[1]:
            return here
        near = np.flatnonzero(wrong <= least + VIEW_Z * math.sqrt(least + 1.0))
        if len(near) == len(offsets) or near[-1] - near[0] + 1 != len(near):
            return here  # every offset alike, or two stretches: nothing placed
        centre = 0.5 * (offsets[near[0]] + offsets[near[-1]])
        spread = max(PLACE_STEP, 0.5 * (offsets[near[-1]] - offsets[near[0]]))
        flat = np.outer(along[:2], along[:2])
        covariance = np.diag([PLACE_FREE**2] * 3)
        covariance[:2, :2] = spread**2 * flat + PLACE_FREE**2 * (np.eye(2) - flat)
        h.filter.update(h.pose + centre * along, covariance)
        self.stats["scans a place was placed by its views"] += 1
        return views[int(np.argmin(np.abs(offsets - centre)))]

    def _follow(self, pose: FloatArray) -> None:
        """Follow the place ``pose`` (scored there as a tracked scan is), unless one followed
        is already there."""
        if any(_same(h.pose, pose) for h in self.hypotheses):
            return
        h = self._start(pose, _proposal_covariance(pose))
        score = self.places.score(self._within, pose)
        h.past, h.past_views, view = self._past(pose, score)
        h.record(score, view)
        h.fitted.append(score)
        self.hypotheses.append(h)

    def _views(self, ranges: list[FloatArray], poses: list[FloatArray]) -> list[View]:
        """The live beams (each of ``ranges``) the saved map's view from each of ``poses``
        contradicts, and those it knows (:meth:`vmp.views.SavedViews.disagreements`)."""
        if not poses:
            return []
        found = self.places.views.disagreements(np.array(ranges), np.array(poses))
        return [(int(wrong), int(known)) for wrong, known in found]

    def _past(self, pose: FloatArray, score: float) -> tuple[list[float], list[View], View]:
        """The scores and views of the scans before this one, oldest first, had the robot been at
        ``pose`` now and moved as scan odometry says: back to the first that misses
        (:data:`KEEP_RATIO` of ``score``), which counts 0, or :data:`WINDOW` scans back; and
        this scan's view from ``pose``.

        Compared with another only over the scans since it was found, a look-alike found a
        few scans after the right place would stay its rival for as long as the two look
        alike: the simulated warehouse's start at scan 1374 of seed 110 would be declared
        after 52 scans, the office's kidnap of seed 113 after 84; compared over the scans
        before too, after 6 each.
        (The bays along an aisle often stay alike: the endpoint score cannot see what tells
        them apart in the world, a beam that would stop short or pass a rack's end.)"""
        out: list[float] = []
        seen: list[tuple[FloatArray, FloatArray]] = [(self._ranges, pose)]  # ranges, pose
        recent = list(self._recent)
        for k in range(len(recent) - 1, 0, -1):  # WINDOW scans at most
            pose = compose(pose, inverse(recent[k][1]))
            points, ranges = recent[k - 1][0], recent[k - 1][2]
            past = self.places.score(points, pose) if len(points) else 0.0
            if past < KEEP_RATIO * score:
                out.append(0.0)
                break
            out.append(past)
            seen.append((ranges, pose))
        now, *views = self._views([r for r, _ in seen], [p for _, p in seen])
        views += [NO_VIEW] * (len(out) - len(views))  # the miss, if any
        return out[::-1], views[::-1], now

    def _tried_here(self) -> set[int]:
        """The milestones searched from about here (within :data:`RETRY_XY` and
        :data:`RETRY_THETA` by odometry): the same view would fail there again."""
        self._tried = {mid: at for mid, at in self._tried.items() if not self._moved_since(at)}
        return set(self._tried)

    def _moved_since(self, at: FloatArray) -> bool:
        """Whether the robot moved more than :data:`RETRY_XY` or turned more than
        :data:`RETRY_THETA` by odometry since it was ``at`` (enough for a new view)."""
        return not _within(at, self._odometry, RETRY_XY, RETRY_THETA)

    def _prune(self) -> None:
        """Drop hypotheses that stopped fitting and ones that met a better one; keep the
        best few. While a place is trusted, the others proposed in doubt of it are followed
        for :data:`WINDOW` scans to outdo it (:meth:`_outdone`), and dropped if they do not:
        each costs a registration a scan."""
        trusted = self._trusted()
        keep: list[Hypothesis] = []

        def rank(h: Hypothesis) -> tuple:
            # The place declared before it was lost is kept while it dead-reckons, however
            # many others are proposed: it may fit again (below, in the decision). Among the
            # places that score about as well as the best, those whose views agree best
            # come first (along the simulated warehouse's aisles many score 1.000, and the
            # right place would be dropped for later ones); views that tell nothing
            # (:data:`VIEW_MOST`) do not rank a place.
            return (-h.trusted, -h.declared, not _as_well(h.score, top),
                    min(_view_share(h), VIEW_MOST), -h.score)

        ranked = self.hypotheses
        if len(ranked) > 1:  # (one place alone, as tracked, needs no ranking: 6 us a scan)
            top = max(h.score for h in ranked)
            ranked = sorted(ranked, key=rank)
        for h in ranked:
            if h.misses > (DEAD_RECKONING if h.declared else DROP_AFTER):
                continue
            if trusted is not None and h is not trusted and len(h.scores) == WINDOW:
                continue
            if any(_same(k.pose, h.pose) for k in keep):
                continue
            keep.append(h)
        self.hypotheses = keep[:MAX_HYPOTHESES]

    def _trusted(self) -> Hypothesis | None:
        return next((h for h in self.hypotheses if h.trusted), None)

    # ---- the decision ----------------------------------------------------------------------

    def _aliased(self, h: Hypothesis) -> bool:
        """Whether another pose near ``h`` explains this scan about as well (the search
        only ever looks around the milestones, and a corridor of pilasters may hold none
        where the robot is), and the scans before it too (:meth:`_told_by_the_past`). The
        places followed that the views tell from ``h`` are not looked for; one a search
        finds that only the views tell apart is followed, to be compared with whichever
        place is best from the next scan on. So is one the scans before do not tell apart at
        all, where the saved map's views vouch for ``h`` (they contradict at most
        :data:`VIEW_MOST` of the beams, so they may tell the two apart on the scans to come):
        found and let go scan after scan, it would hold the decision for as long as the bays
        read alike (the simulated warehouse's kidnap of seed 116: the bay 2.4 m along the
        aisle, found again scan after scan from the 14th, would delay the robot's
        localization to the 45th; followed, its views tell it apart at the next scan). Where
        the views tell nothing, a place followed beside ``h`` only holds the decision longer:
        the Intel part's second half, localized on 69.5 % of its scans, would be on 57.1 %
        with every such find followed."""
        known = [h.pose] + [o.pose for o in self._seen_apart(h)]
        live = search_points(self._points)
        vouched = _view_share(h) <= VIEW_MOST
        followed = False
        for _ in range(MAX_ALIKE):
            found = self._near(h, _least_as_well, live, known)
            if found is None or not _as_well(found[1], found[2], GRID_MARGIN):
                return followed
            told = self._told_by_the_past(h, found[0])
            if told == "views" or (told is None and vouched):
                self._follow(found[0])
            if told is None:
                return True
            followed = followed or told == "views"
            known.append(found[0])
        return True

    def _near(self, h: Hypothesis, least: Callable[[float], float], live: FloatArray,
              known: list[FloatArray] | None = None) -> tuple[FloatArray, float, float] | None:
        """The best pose within :data:`ALIAS_WINDOW` of ``h`` and at least
        :data:`ALIAS_APART` from it and from every ``known`` one (map frame) where the points
        ``live`` (in this scan's frame) score ``least(mine)`` or more, that score and ``mine``
        (their score at ``h``); None when there is none."""
        if len(live) < MIN_POINTS or len(self.places.points) < MIN_POINTS:
            return None
        grid = self.places.grid
        mine = grid.score(live, h.pose)
        away = np.reshape(known if known else [h.pose], (-1, 3))
        other = search(grid, live, h.pose, ALIAS_WINDOW, ALIAS_TURN, least(mine),
                       exclude=(away, *ALIAS_APART))
        return None if other is None else (other.pose, other.score, mine)

    def _searched_with(self, h: Hypothesis) -> FloatArray:
        """The points the search along the saved path for look-alikes of ``h`` matches
        (:func:`search_points`): the last scans ``h`` explains in a row (back to its first
        miss, :data:`SEARCH_SCANS` at most), each carried into this scan's frame along scan
        odometry. A look-alike must explain them all, as the scans before are asked to of a
        place found (:meth:`_told_by_the_past`)."""
        explained = 0
        for score in reversed(h.history):
            if score <= 0.0:
                break
            explained += 1
        recent = list(self._recent)
        scans = max(1, min(explained, len(recent), SEARCH_SCANS))  # this scan at least
        carried, at = [], np.zeros(3)  # each scan's frame in this scan's
        for k in range(len(recent) - 1, len(recent) - 1 - scans, -1):
            carried.append(transform_points(at, recent[k][0]))
            at = compose(at, inverse(recent[k][1]))
        return search_points(np.vstack(carried))

    def _told_by_the_past(self, best: Hypothesis, pose: FloatArray) -> str | None:
        """How the scans before this one tell ``pose`` (a search's, registered against the
        map where that fits) from ``best``, carried back from there along scan odometry:
        "scores" when they are explained clearly less well than ``best`` explains them, over
        the scans both have (:attr:`Hypothesis.history`; not :func:`_as_well`), "views" when
        they are not but the views from there agree clearly worse with them
        (:func:`_seen_clearly_better`, at :data:`FOUND_VIEW_MARGIN`), None when neither.
        For a place declared before, over the scans it has fitted in a row since it was lost
        only: the robot may have been carried off meanwhile, and the scans before say nothing
        of where to. (Were such a place never told apart so, the Intel part's second half
        started 4 scans late would stay ambiguous for 544 scans after its place is lost and
        found again: a look-alike a few metres along the corridor scores as well in the
        search's grid on one scan.)"""
        if best.declared:
            mine = list(best.scores)[len(best.scores) - best.streak:]
            my_views = list(best.views)[len(best.views) - best.streak:]
        else:
            mine, my_views = best.history, best.view_history
        if not mine:
            return None
        pose = self._registered(pose)
        score = self.places.score(self._within, pose)
        scores, views, now = self._past(pose, score)
        theirs = (scores + [score])[-WINDOW:]
        their_views = (views + [now])[-WINDOW:]
        if not _as_well(*_compared(theirs, mine)):
            return "scores"
        if _seen_clearly_better(my_views, their_views, FOUND_VIEW_MARGIN):
            return "views"
        return None

    @staticmethod
    def _doubted(h: Hypothesis) -> bool:
        """Whether the place trusted explains the scans clearly worse than when it was
        declared (:func:`_clearly_better`). A robot carried a few metres along a warehouse
        aisle still fits the old place, scan after scan (the simulated warehouse: 3.4 m off,
        scoring 0.73 and then 0.93-0.96 where the right place scores 0.99), and its usual
        score follows it down; the places proposed meanwhile may show where it is."""
        return _clearly_better(h.reference_score, h.score)

    def _outdone(self, trusted: Hypothesis) -> Hypothesis | None:
        """Another place followed that explains the last scans clearly better than the
        place trusted, over the scans since the robot may have been there (those it was
        followed and those before that it explains: :func:`_over_scans_since`), and that
        the robot may have come to from the place trusted (:func:`_reachable`); None when
        none does."""
        for h in self.hypotheses:
            if h is trusted or h.misses or h.fits < MIN_FITS or not _reachable(h, trusted):
                continue
            if _clearly_better(*_over_scans_since(h, trusted)):
                return h
        return None

    def _outseen(self, trusted: Hypothesis) -> Hypothesis | None:
        """Another place followed that explains the scans since it was followed about as well
        as the place trusted, whose views contradict the scans (:func:`_seen_off`), with views
        that agree clearly better over them (:func:`_seen_clearly_better`); None when none
        does, or the views of the place trusted agree. Not
        over the scans before it was followed, carried back along scan odometry: the robot
        was carried to it meanwhile, and the right place explains those less well (the
        simulated warehouse's kidnap of seed 134: 0.954 against 1.000 over the twenty)."""
        if not _seen_off(trusted):
            return None
        for h in self.hypotheses:
            if h is trusted or h.misses or h.fits < MIN_FITS:
                continue
            if (_as_well(*_compared(list(h.scores), list(trusted.scores), unexplained=True))
                    and _seen_clearly_better(list(h.views), list(trusted.views))):
                return h
        return None

    def _carried_before(self, found: Hypothesis, old: Hypothesis) -> None:
        """The robot was carried from ``old`` before ``found`` was followed: the scans before
        are forgotten (each place's scans carried back, and the last scans new places are
        carried back over), as they are for a place declared before the robot was lost
        (:func:`_over_common_scans`). Compared over them, the right bay of the simulated
        warehouse's kidnap of seed 134 would take over after 9 scans but be declared after
        35: neither the scans nor the views from before the kidnap tell it from the bays
        alike found next."""
        while len(self._recent) > len(found.scores):
            self._recent.popleft()
        for h in self.hypotheses:
            if h is not old:
                h.past, h.past_views = [], []

    def _decide(self) -> State:
        trusted = self._trusted()
        if trusted is not None and trusted.misses < LOST_AFTER:
            found = self._outseen(trusted)
            if found is not None:
                self.stats["times a place the views doubted gave way"] += 1
                self._carried_before(found, trusted)
            else:
                better = self._outdone(trusted)
                if better is None:
                    return State.LOCALIZED
                if _nearby(better.pose, trusted.pose):
                    # The same place, better placed (the filter had drifted off it): the
                    # robot is not lost.
                    return self._declare(better, "times a doubted place was placed better")
                self.stats["times a doubted place gave way"] += 1
            # As after a miss: to resume, it must fit again scan after scan, and be compared
            # over those scans (over a longer window its scores from before the robot was
            # carried would bring it back at once).
            trusted.streak = 0
        if trusted is not None:
            # Lost: the place must win again against the others, as at the start (a robot
            # carried to a look-alike place may fit the old one again).
            trusted.trusted = False
            trusted.searches = 0
            self._reckoned, self._driven = trusted.pose.copy(), 0.0
            self._reckon_at = None
            trusted = None
            self._lost = True
        # Not localized (or lost): the best-scoring hypothesis that fits now, has fitted and
        # outlived enough searches, with no other scoring near it, is the place.
        waiting = State.LOST if self._lost else State.SEARCHING
        fitting = [h for h in self.hypotheses if h.misses == 0]
        if not fitting:
            return waiting
        resumed = self._resumed(fitting)
        if resumed is not None and not self._aliased(resumed):
            # (Unchecked for a look-alike nearby, the simulated office's old place would resume
            # after a kidnap to another stretch of its pilastered corridor.)
            return self._declare(resumed, "times the lost place resumed")
        best = self._told_apart(max(fitting, key=lambda h: h.score))
        if best is None:
            return State.AMBIGUOUS
        if (best.searches < MIN_SEARCHES or best.fits < MIN_FITS or best.score < MIN_SCORE
                or _seen_off(best)):
            return waiting
        if self._aliased(best):
            self.stats["places aliased nearby"] += 1
            return State.AMBIGUOUS
        if self._elsewhere(best):
            self.stats["places alike along the path"] += 1
            return State.AMBIGUOUS
        if self._bettered(best):
            self.stats["places bettered in the whole map"] += 1
            return State.AMBIGUOUS
        return self._declare(best, "times localized")

    def _told_apart(self, best: Hypothesis) -> Hypothesis | None:
        """The place among ``best`` (the best score) and its rivals (:func:`_rival`) that
        the saved map's views tell from every other: ``best`` when it has no rival, the one
        fitting place whose views agree clearly better with the scans than those of every
        other place that is its rival or ``best``'s (:func:`_seen_clearly_better`), None when
        there is none (ambiguous)."""
        rivals = [h for h in self.hypotheses if h is not best and _rival(h, best)]
        if not rivals:
            return best
        contenders = [best, *rivals]
        for h in sorted((h for h in contenders if h.misses == 0), key=_view_share):
            apart = self._seen_apart(h)
            if all(o in apart for o in self.hypotheses
                   if o is not h and (o in contenders or _rival(o, h))):
                self.stats["scans whose rivals the map's views told apart"] += 1
                return h
        return None

    def _seen_apart(self, best: Hypothesis) -> list[Hypothesis]:
        """The places followed whose views agree clearly worse with the scans than those of
        ``best`` (:func:`_seen_clearly_better`)."""
        return [h for h in self.hypotheses
                if h is not best and _seen_clearly_better(*_over_common_views(best, h))]

    def _elsewhere(self, best: Hypothesis) -> bool:
        """Whether the scan fits about as well somewhere along the saved path far from
        ``best`` (:meth:`_along_path`). Searched once, and again only once the robot moved
        :data:`RETRY_XY` or turned :data:`RETRY_THETA` by odometry: until then the answer
        stands.

        The signatures propose only places with a milestone, and the mapper records none
        where the view matches one recorded already: the simulated corridor's map has
        milestones at 1-2 m and 34.6-39.3 m of its 39 m. A robot carried to 12.6 m can only
        be found at a look-alike, and one 28 m away, in step with the pilasters, would be
        declared (0.97; the right stretch scores 0.98-0.99 but is never proposed).

        A place found is followed from then on, and left out of the later searches once it
        has fitted :data:`MIN_FITS` scans and is no rival of the best (:func:`_left_behind`):
        in the simulated warehouse the other loading dock, 14 m along the aisle, matches
        single scans about as well in the search's grid, scores 0.98-0.99 over twenty where
        the right place scores 1.000, and would be found again at every search, holding the
        decision for 40-70 scans. Unless it explains this scan about as well as the best
        (:func:`_explains_now`): a place followed since before the robot was carried there
        explains the scans from before clearly worse, and, left out, would let a look-alike
        be declared (the simulated corridor's kidnap of seed 109: the right place explains
        each scan from the 10th after at 1.000, but the twenty at 0.85-0.97, and the west
        end, 38 m off and facing the other way, scores 1.000)."""
        if best.checked_at is not None and not self._moved_since(best.checked_at):
            return best.alike
        best.checked_at = self._odometry.copy()
        best.alike = False
        # The places followed and told apart from the best already are not looked for again;
        # one not told apart is, and holds the decision when found.
        seen_apart = [h.pose for h in self._seen_apart(best) if not _left_behind(h, best)]
        left = [h.pose for h in self.hypotheses
                if h is best or (_left_behind(h, best) and not _explains_now(h, best))]
        left += seen_apart
        live = self._searched_with(best)
        by_views = False  # whether the scans before told a place found apart by its views
        for _ in range(MAX_ALIKE):
            found = self._along_path(best.pose, _least_as_well, live, left)
            if found is None:
                return best.alike
            told = self._told_by_the_past(best, found.pose)
            if told is None:
                # Followed, and compared with the best from the next scan on.
                self._follow(found.pose)
                best.alike = True
                return best.alike
            # Told apart by the scans before, by their scores or their views: not followed.
            # (Followed, a place the views told apart would be compared with the best over
            # the last scans both have views for, the last MIN_VIEWS of them included, and
            # the bays of an aisle read alike once the robot has moved on: at the simulated
            # warehouse's kidnap of seed 100 the views of the bays 7.5-15 m along the aisle
            # contradict 10-60 of 180 beams on each of the ten scans before they are found,
            # the right bay's none, then both 0-4 a scan.)
            if told == "views":
                by_views = True
                self.stats["places along the path the views of the scans before told apart"] += 1
            left.append(found.pose)
        # Out of tries: every place found was told apart by the scans before. Where the
        # views told some apart, the search went farther than the scores alone would have
        # let it, and decides nothing (deciding, it would declare wrong stretches among the
        # simulated corridor's look-alikes: seeds 104, 106, 112 and 138).
        best.alike = best.alike or bool(seen_apart) or by_views
        return best.alike

    def _bettered(self, best: Hypothesis) -> bool:
        """Whether a pose anywhere in the map explains this scan clearly better than ``best``
        (searched as :meth:`_anywhere` searches), now followed, with a pose about as good
        elsewhere if there is one. Searched once before ``best`` is declared, and again only
        once the robot has moved since (:meth:`_moved_since`).

        The signatures propose only places with a milestone near, and the whole map is
        searched only while they propose none: unsearched, on ACES's cut at 0.625 a
        look-alike they propose would be declared 5.2 m and 90 deg off where the robot, 3.3 m
        from the nearest milestone, explains the scan at 0.934 against 0.831, and one found
        where the robot dead-reckons 34.4 m and 176 deg off where it explains it at 1.000
        against 0.957, with no place near the robot followed."""
        if best.bettered_at is not None and not self._moved_since(best.bettered_at):
            return False
        best.bettered_at = self._odometry.copy()
        live = search_points(self._points)
        if len(live) < MIN_POINTS:
            return False
        least = max(MIN_SCORE, _least_clearly_better(self.places.grid.score(live, best.pose)))
        if least >= 1.0:
            return False
        self.stats["searches of the whole map before a place is declared"] += 1
        found, other = _best_and_alike(
            lambda floor, exclude: self.places.everywhere(live, floor, exclude), least)
        # Followed, with a pose about as good elsewhere too (ACES's corridor facing the other
        # way), to be compared with the best over the scans to come.
        for pose in [m.pose for m in (found, other) if m is not None]:
            self._follow(self._registered(pose))
        return found is not None

    def _along_path(self, pose: FloatArray, least: Callable[[float], float], live: FloatArray,
                    known: list[FloatArray]) -> Match | None:
        """A pose along the saved path, farther than :data:`ALIAS_WINDOW` from ``pose`` and
        at least :data:`ALIAS_APART` from every ``known`` one, where the points ``live`` (in
        this scan's frame) score ``least(mine)`` or more (``mine``: their score at ``pose``),
        facing the path as the robot faces it at ``pose`` or the other way along it (the first
        found); None when there is none."""
        return next(self._all_along_path(pose, least, live, known), None)

    def _all_along_path(self, pose: FloatArray, least: Callable[[float], float],
                        live: FloatArray, known: list[FloatArray]) -> Iterator[Match]:
        """The poses :meth:`_along_path` would find, one after another in the path's order,
        each searched on from the path's sample after the last one's (one pass along the
        path in all)."""
        if (len(live) < MIN_POINTS or len(self.places.path) == 0
                or len(self.places.points) < MIN_POINTS):
            return
        path, grid = self.places.path, self.places.grid
        floor = least(grid.score(live, pose))
        apart = np.hypot(*(path[:, :2] - pose[:2]).T)
        offset = relative(path[np.argmin(apart)], pose)  # as the robot stands to the path
        exclude = (np.array(known).reshape(-1, 3), *ALIAS_APART)
        # A small search a metre along the path, facing along it either way, most pruned.
        samples = np.repeat(path[apart > ALIAS_WINDOW], 2, axis=0)
        samples[1::2, 2] += math.pi
        centers = compose(samples, offset)
        while len(centers):
            found = first_match(grid, live, centers, PATH_WINDOW_XY, PATH_WINDOW_THETA, floor,
                                exclude=exclude)
            if found is None:
                return
            yield found[1]
            centers = centers[found[0] + 1:]

    def _resumed(self, fitting: list[Hypothesis]) -> Hypothesis | None:
        """The place declared before the robot was lost, when it fits again: its last
        :data:`MIN_FITS` scans in a row, scoring :data:`MIN_SCORE` on average, with no place
        that explains those scans clearly better. The robot was there; a place elsewhere that
        explains them only about as well (the Intel part's look-alike rooms) is no reason to
        doubt it, where a robot carried elsewhere would not fit the old place at all."""
        lost = next((h for h in fitting if h.declared), None)
        if lost is None or lost.streak < MIN_FITS or _seen_off(lost):
            return None
        n = lost.streak
        mine = float(np.mean(list(lost.scores)[-n:]))
        if mine < MIN_SCORE:
            return None
        for h in self.hypotheses:
            if h is lost or h.fits < MIN_FITS:
                continue
            theirs = float(np.mean(list(h.scores)[-min(n, len(h.scores)):]))
            if _clearly_better(theirs, mine):
                return None
        return lost

    def _declare(self, best: Hypothesis, count: str) -> State:
        """Localized on ``best``. The others are dropped: while localized nothing proposes
        places, so none of them could gain a find, and following them would cost a
        registration a scan each."""
        best.trusted = best.declared = True
        best.reference_score = best.score
        best.doubts = best.view_doubts = 0
        vouched = _view_share(best) <= VIEW_MOST
        best.declared_views = [v for v in best.view_history if v[1]] if vouched else []
        self._lost = False
        self._reckoned = None
        self.hypotheses = [best]
        self.stats[count] += 1
        return State.LOCALIZED


def _best_and_alike(find: Callable[[float, tuple | None], Match | None], least: float
                    ) -> tuple[Match | None, Match | None]:
    """The pose ``find(least, None)`` returns, and the best pose ``find`` returns farther than
    :data:`ANYWHERE_APART` from it that scores about as well (:func:`_least_as_well`); None
    for either where there is none."""
    best = find(least, None)
    if best is None:
        return None, None
    return best, find(_least_as_well(best.score), (best.pose.reshape(1, 3), *ANYWHERE_APART))


def _proposal_covariance(pose: FloatArray) -> FloatArray:
    """How well a place proposed at ``pose`` is known (:data:`PROPOSAL_SIGMA`), map frame."""
    return rotate_covariance(np.diag(np.square(PROPOSAL_SIGMA)), pose[2])


def _rival(h: Hypothesis, best: Hypothesis) -> bool:
    """Whether ``h`` explains the scans about as well as ``best``, over the scans both were
    followed (one proposed just now blocks only when it already explains more)."""
    if h.known_fits < MIN_FITS:
        return h.score >= best.score
    return _as_well(*_over_common_scans(h, best))


def _left_behind(h: Hypothesis, best: Hypothesis) -> bool:
    """Whether ``h``, followed :data:`MIN_FITS` scans or more, is no rival of ``best`` over
    the scans both were followed (:func:`_rival`)."""
    return h.known_fits >= MIN_FITS and not _rival(h, best)


def _explains_now(h: Hypothesis, best: Hypothesis) -> bool:
    """Whether ``h`` explains this scan about as well as ``best`` does (:func:`_as_well`)."""
    return bool(h.scores and best.scores and _as_well(h.scores[-1], best.scores[-1]))


def _over_common_scans(h: Hypothesis, other: Hypothesis) -> tuple[float, float]:
    """The mean scores of ``h`` and ``other`` over the last scans both have scores for (those
    before they were proposed included: :attr:`Hypothesis.history`), but for those neither
    explains: a scan both miss says nothing of which is the better. (A robot carried off
    misses the scans before at every place it may have been carried to, and counted, such a
    miss in both pasts would keep the right place and one 6 m off rivals until it leaves the
    window: recovering in the simulated office would take 19 scans rather than 12.) A place
    declared before is compared over the scans both were followed only: the robot was there
    before it was carried off, and the places it may have been carried to miss those scans
    (compared over them, the old place would stay a rival of the right one for up to 7 scans
    more after the simulated warehouse's kidnaps)."""
    if h.declared or other.declared:  # over the scans both were followed
        return _compared(list(h.scores), list(other.scores), unexplained=True)
    return _compared(h.history, other.history)


def _over_common_views(h: Hypothesis, other: Hypothesis) -> tuple[list[View], list[View]]:
    """The views of ``h`` and ``other`` over the scans :func:`_over_common_scans` compares
    their scores on."""
    if h.declared or other.declared:
        return list(h.views), list(other.views)
    return h.view_history, other.view_history


def _least_sure(h: Hypothesis) -> tuple[FloatArray, FloatArray]:
    """The direction of position ``h``'s filter is least sure of (a unit pose increment,
    map frame), and the offsets along it its views are taken from
    (:meth:`Localizer._placed_by_views`): :data:`PLACE_STEP` apart, out to
    :data:`PLACE_SIGMAS` standard deviations either way, :data:`PLACE_MOST` steps at most,
    0 in the middle; 0 alone for a place trusted: it is registered against the map as it
    is tracked."""
    if h.trusted:
        return np.zeros(3), np.zeros(1)
    cov = h.filter.covariance
    steps = min(int(PLACE_SIGMAS * math.sqrt(widest_variance(cov)) / PLACE_STEP), PLACE_MOST)
    return np.append(widest_direction(cov), 0.0), PLACE_STEP * np.arange(-steps, steps + 1)


def _view_share(h: Hypothesis) -> float:
    """The share of the live beams its views contradict, over the scans they know (1 when
    they know none)."""
    wrong = sum(d for d, _ in h.view_history)
    known = sum(k for _, k in h.view_history)
    return wrong / known if known else 1.0


def _seen_clearly_better(mine: list[View], theirs: list[View], margin: float = VIEW_MARGIN
                         ) -> bool:
    """Whether the views of one place agree clearly better with the scans than another's,
    over the last scans both have a view for, and over the last :data:`MIN_VIEWS` of them
    too (a place just proposed is still settling, and its first scans' views may
    contradict many beams along a wall seen at a grazing angle): the first's contradict
    :data:`VIEW_MOST` of the beams at most, the other's more
    than :data:`VIEW_FACTOR` times the share of the beams the first's contradict, plus
    ``margin``, and by :data:`VIEW_Z` standard deviations of the difference (two shares of
    beams, binomial) or more."""
    n = min(len(mine), len(theirs))
    pairs = [(a, b) for a, b in zip(mine[len(mine) - n:], theirs[len(theirs) - n:], strict=True)
             if a[1] and b[1]]
    if len(pairs) < MIN_VIEWS:
        return False
    mine, theirs = [a for a, _ in pairs], [b for _, b in pairs]
    return (_views_apart(mine, theirs, margin)
            and _views_apart(mine[-MIN_VIEWS:], theirs[-MIN_VIEWS:], margin))


def _seen_off(h: Hypothesis) -> bool:
    """Whether the views of a place declared where they vouched for it
    (:attr:`Hypothesis.declared_views`) now contradict the scans: over its last
    :data:`MIN_VIEWS` scans with a view, more than :data:`VIEW_MOST` of the beams, and
    clearly more than over the scans before it was declared (:func:`_views_apart`)."""
    if not h.declared_views:
        return False
    now = _last_views(h)
    if len(now) < MIN_VIEWS:
        return False
    share = sum(w for w, _ in now) / sum(k for _, k in now)
    return share > VIEW_MOST and _views_apart(h.declared_views, now, VIEW_MARGIN)


def _last_views(h: Hypothesis) -> list[View]:
    """The views of ``h``'s last :data:`MIN_VIEWS` scans that had one (fewer when it has
    fewer)."""
    return [v for v in h.views if v[1]][-MIN_VIEWS:]


def _views_apart(mine: list[View], theirs: list[View], margin: float) -> bool:
    """:func:`_seen_clearly_better` over views of the first place (``mine``) and of the
    other (``theirs``)."""
    wrong_a = sum(w for w, _ in mine)
    known_a = sum(k for _, k in mine)
    wrong_b = sum(w for w, _ in theirs)
    known_b = sum(k for _, k in theirs)
    share_a, share_b = wrong_a / known_a, wrong_b / known_b
    if share_a > VIEW_MOST or share_b < VIEW_FACTOR * share_a + margin:
        return False
    pooled = (wrong_a + wrong_b) / (known_a + known_b)
    spread = math.sqrt(pooled * (1.0 - pooled) * (1.0 / known_a + 1.0 / known_b))
    return share_b - share_a >= VIEW_Z * spread


def _reachable(h: Hypothesis, trusted: Hypothesis) -> bool:
    """Whether the robot, tracked on the place ``trusted``, may be at ``h``: ``h`` lies
    within :data:`ALIAS_WINDOW` of it, turned less than :data:`ANYWHERE_APART` allows (the
    filter may have slid along a corridor, turned as far as one peak of a scan's score
    spreads), or the scans before ``h`` was followed, carried back from it along scan
    odometry, stop fitting it within :data:`WINDOW` (:attr:`Hypothesis.past`: the robot was
    carried there). A place farther off that explains those scans all the way back is a
    look-alike of the place trusted along the path the robot drove, not where it went: the
    scans went on fitting the place trusted, and no kidnap broke them. (On real logs, where
    the saved map is thinner at the right place than at its look-alike, such places would
    outdo the right place: ACES cut at 0.65, the mirror of a corridor 4.9 m off and facing
    the other way, 0.985 against 0.900; fr079's second half, the corridor 19 m off facing
    the other way, 0.935 against 0.846.)"""
    if _within(trusted.pose, h.pose, ALIAS_WINDOW, ANYWHERE_APART[1]):
        return True
    return len(h.past) < WINDOW - 1 or 0.0 in h.past


def _over_scans_since(h: Hypothesis, trusted: Hypothesis) -> tuple[float, float]:
    """The mean scores of ``h`` and the place ``trusted`` over the last scans ``h`` was
    followed and those before that it explains, back to the first it misses. Not over that
    miss: a robot carried off was at the trusted place then, and the place it was carried to
    misses it (counted, the simulated warehouse's kidnap of seed 109 would stay at the old
    place for 19 scans rather than 12). But over the scans before that it explains: the
    office's kidnap of seed 113 is found after 6 scans, not 84. (Along the warehouse's aisles
    a scan before the kidnap may fit the new place too: seed 123's stays at the old place for
    41 scans, against 30 compared over the scans followed only.)"""
    past = h.past[1:] if h.past and h.past[0] == 0.0 else h.past
    return _compared((past + list(h.scores))[-WINDOW:], list(trusted.scores), unexplained=True)


def _compared(mine: list[float], theirs: list[float], unexplained: bool = False
              ) -> tuple[float, float]:
    """The means of two places' scores over the last scans both have, but for those
    neither explains unless ``unexplained`` (:func:`_over_common_scans`)."""
    n = min(len(mine), len(theirs))
    pairs = [(a, b) for a, b in zip(mine[-n:], theirs[-n:], strict=True)
             if unexplained or a or b]
    if not pairs:
        return 0.0, 0.0
    return float(np.mean([a for a, _ in pairs])), float(np.mean([b for _, b in pairs]))


def _as_well(score: float, best: float, margin: float = RIVAL_MARGIN) -> bool:
    """Whether a place scoring ``score`` explains the scans about as well as one scoring
    ``best``: it leaves fewer than :data:`RIVAL_FACTOR` times the share of points the best
    leaves unexplained, plus ``margin`` (:data:`RIVAL_MARGIN` for exact scores,
    :data:`GRID_MARGIN` for a search grid's)."""
    return 1.0 - score < RIVAL_FACTOR * (1.0 - best) + margin


def _clearly_better(score: float, than: float, margin: float = RIVAL_MARGIN) -> bool:
    """Whether a place scoring ``score`` explains the scans clearly better than one scoring
    ``than``: it leaves unexplained less than the other's share over :data:`RIVAL_FACTOR`,
    less ``margin`` (:data:`RIVAL_MARGIN` for exact scores, :data:`GRID_MARGIN` for a
    search grid's)."""
    return 1.0 - score < (1.0 - than) / RIVAL_FACTOR - margin


def _least_clearly_better(than: float) -> float:
    """The score above which a place explains the scans clearly better than one scoring
    ``than`` (:func:`_clearly_better` with :data:`GRID_MARGIN`), for a grid search to prune
    below."""
    return 1.0 - ((1.0 - than) / RIVAL_FACTOR - GRID_MARGIN)


def _least_as_well(best: float) -> float:
    """The score above which a place explains the scans about as well as one scoring
    ``best`` (:func:`_as_well` with :data:`GRID_MARGIN`), for a grid search to prune
    below."""
    return 1.0 - (RIVAL_FACTOR * (1.0 - best) + GRID_MARGIN)


def _same_view(before: FloatArray, now: FloatArray) -> bool:
    """Whether most beams of two scans of one scanner read the same: within
    :data:`vmp.frontend.NEW_VIEW_XY` of each other, or no return in both."""
    with np.errstate(invalid="ignore"):  # inf - inf: no return in either, compared below
        same = np.abs(now - before) < NEW_VIEW_XY
    same |= np.isinf(now) & np.isinf(before)
    return 2 * int(np.count_nonzero(same)) > len(same)


def _within(a: FloatArray, b: FloatArray, xy: float, theta: float) -> bool:
    """Whether pose ``b`` lies within ``xy`` (m) of pose ``a`` and turned at most ``theta``
    (rad) from it."""
    d = relative(a, b)
    return math.hypot(d[0], d[1]) <= xy and abs(d[2]) <= theta


def _nearby(a: FloatArray, b: FloatArray) -> bool:
    """Whether two poses lie within :data:`ANYWHERE_APART` of each other: one peak of the
    scan's score in the map, not two places."""
    return _within(a, b, *ANYWHERE_APART)


def _same(a: FloatArray, b: FloatArray) -> bool:
    return _within(a, b, SAME_XY, SAME_THETA)
