"""Region tree over a space of any dimension with competence-progress interest (paper Sec. 2.4.3-2.4.4,
Algorithm 2 "UpdateRegions"). ROS-free.

The same tree serves SAGG-RIAC (regions of the task space Y, values = competences Γ) and
ACTUATOR-RIAC (regions of the sensorimotor space (α, Δα), values = minus the prediction error), since
RIAC's interest is the same absolute derivative over a sliding window.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .leaf_interests import LeafInterests


def half_window(n, zeta):
    """``h = min(ζ, n) // 2``: the size of each half of the interest window of a region holding
    ``n`` values (:func:`interest`); 0 for fewer than two values.

    Parameters
    ----------
    n : int or ndarray of int
        Number of values of the region (or of each of several regions).
    zeta : int
        Interest window ζ.

    Returns
    -------
    int or ndarray of int
        h, of the same shape as ``n``.
    """
    return min(zeta, n) // 2 if isinstance(n, int) else np.minimum(zeta, n) // 2


def window_interest(signed_sum, h):
    """The interest of a window from its signed sum: ``|Σ older half − Σ recent half| / 2h``
    (:func:`interest`); the one place the formula's last step is written, for one region or many.

    Parameters
    ----------
    signed_sum : float or ndarray
        ``Σ older half − Σ recent half`` of each window (0 for an empty window).
    h : int or ndarray of int
        Each window's half size (:func:`half_window`), of the shape of ``signed_sum``.

    Returns
    -------
    float or ndarray
        The interest, >= 0; 0 where h = 0 (the window is empty, its signed sum 0, and the
        divisor 1 instead of 0).
    """
    return abs(signed_sum) / (2 * h + (h == 0))


def interest(values: np.ndarray, zeta: int) -> float:
    """Interest of a region: paper Sec. 2.4.3, equation (interest) / Algorithm 2.

    ``|Σ older half − Σ recent half| / ζ`` over the ``ζ`` most recent values of the region, in the
    order they were added. Vague in the paper: both sums include the middle element and the region
    may hold fewer than ζ values. Choice: the window is ``w = min(ζ, n)`` values split into two halves
    of ``h = w // 2`` (:func:`half_window`; the oldest value is dropped when w is odd), divided by
    ``2h`` (= ζ for a full window with even ζ; :func:`window_interest`); fewer than two values give
    interest 0. :func:`split_qualities` takes the same windows of many candidate regions at once.

    Parameters
    ----------
    values : ndarray, shape (n,)
        The region's n values (competences Γ, or minus prediction errors for ACTUATOR-RIAC) in
        the order they were added, oldest first.
    zeta : int
        Interest window ζ.

    Returns
    -------
    float
        The region's interest, >= 0 (0 for fewer than two values).
    """
    n = len(values)
    h = half_window(n, zeta)
    if h == 0:
        return 0.0
    recent = values[n - h:n]
    older = values[n - 2 * h:n - h]
    return window_interest(float(older.sum()) - float(recent.sum()), h)


def proportional(weights: np.ndarray) -> np.ndarray:
    """Choice probabilities proportional to non-negative ``weights``; uniform when they sum to 0.
    The last step of every interest-driven choice here (regions, mixture components, grid cells),
    each of whose sources leaves the all-zero case open or uniform.

    Parameters
    ----------
    weights : ndarray, shape (K,)
        Non-negative weights of the K choices, K >= 1.

    Returns
    -------
    ndarray, shape (K,)
        Probabilities summing to 1: ``weights / weights.sum()``, or ``1 / K`` each when the sum
        is 0.
    """
    total = weights.sum()
    return np.full(len(weights), 1.0 / len(weights)) if total <= 0 else weights / total


def interest_probabilities(interests: np.ndarray) -> np.ndarray:
    """Region selection probabilities of SAGG-RIAC's goal mode 1: paper Sec. 2.4.4, equation
    (tex line 238): ``P_n = (interest_n − min_i interest_i) / Σ_i (interest_i − min_i interest_i)``.

    When every region has the same interest (the sum is 0) the choice is uniform (our choice: the
    paper's formula is undefined there). ACTUATOR-RIAC chooses its regions with the same formula.

    Parameters
    ----------
    interests : array_like, shape (L,)
        Interests of the L regions to choose among (the leaves), L >= 1.

    Returns
    -------
    ndarray, shape (L,)
        Selection probability of each region, summing to 1.
    """
    it = np.asarray(interests, dtype=float)
    return proportional(it - it.min())


@dataclass(eq=False)
class Region:
    """A node of the tree: an axis-aligned box and the points attempted inside it, in time order.

    ``interest`` is computed lazily (on read) from the last ζ values, so adding points is cheap and
    the interest is evaluated at most once per goal selection."""

    id: int
    lower: np.ndarray
    upper: np.ndarray
    points: np.ndarray  # (capacity, d) storage; rows [:count] are filled
    values: np.ndarray  # (capacity,) competences (or -errors), same order
    count: int = 0
    zeta: int = 20
    _interest: float = 0.0
    _dirty: bool = False
    children: tuple["Region", "Region"] | None = None
    split_dim: int = -1
    split_value: float = 0.0
    interest_sets: ClassVar[int] = 0  # interests set by hand, of any region (LeafInterests notices)

    def add(self, y: np.ndarray, value: float) -> None:
        """Append the point ``y`` and its value (time order), growing the storage when it is full; the
        interest is recomputed at its next read.

        Parameters
        ----------
        y : ndarray, shape (d,)
            The point; d = the tree's dimension (m for the task space Y, 2n for ACTUATOR-RIAC's
            (α, Δα)).
        value : float
            Its value: competence Γ (SAGG-RIAC) or minus the prediction error (ACTUATOR-RIAC).
        """
        if self.count == len(self.values):
            cap = max(8, 2 * len(self.values))
            self.points = np.resize(self.points, (cap, self.points.shape[1]))
            self.values = np.resize(self.values, cap)
        self.points[self.count] = y
        self.values[self.count] = value
        self.count += 1
        self._dirty = True

    @property
    def interest(self) -> float:
        if self._dirty:
            self._interest = interest(self.values[: self.count], self.zeta)
            self._dirty = False
        return self._interest

    @interest.setter
    def interest(self, value: float) -> None:  # for tests and restored snapshots
        self._interest = float(value)
        self._dirty = False
        Region.interest_sets += 1

    @property
    def filled_points(self) -> np.ndarray:
        return self.points[: self.count]

    @property
    def filled_values(self) -> np.ndarray:
        return self.values[: self.count]

    def contains(self, y: np.ndarray) -> bool:
        """Whether ``y`` lies in the region's closed box (faces included).

        Parameters
        ----------
        y : ndarray, shape (d,)
            A point of the tree's space (d = its dimension).

        Returns
        -------
        bool
            True when ``lower <= y <= upper`` in every dimension.
        """
        return bool(np.all(y >= self.lower) and np.all(y <= self.upper))

    def mean_value(self) -> float:
        """Mean of the region's values (its mean competence); 0 when it holds no point.

        Returns
        -------
        float
            The mean of the values held, or 0.0 for an empty region.
        """
        return float(self.filled_values.mean()) if self.count else 0.0


@dataclass
class SplitChoice:
    dim: int
    value: float
    quality: float
    left_count: int
    right_count: int


def split_quality(values_left: np.ndarray, values_right: np.ndarray, zeta: int) -> float:
    """Split quality of paper Sec. 2.4.4: ``card(R1)·card(R2)·|interest(R1) − interest(R2)|``.

    Parameters
    ----------
    values_left : ndarray, shape (n1,)
        Values of the n1 points that go to R1, in the order they were added.
    values_right : ndarray, shape (n2,)
        Values of the n2 points that go to R2, in the order they were added.
    zeta : int
        Interest window ζ of :func:`interest`.

    Returns
    -------
    float
        The quality ``n1 · n2 · |interest(R1) − interest(R2)|``, >= 0.
    """
    return len(values_left) * len(values_right) * abs(
        interest(values_left, zeta) - interest(values_right, zeta)
    )


def split_qualities(values: np.ndarray, left: np.ndarray, zeta: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`split_quality` of many candidate splits of one region at once: ``left`` (N, C) says,
    per candidate, which of the region's N points (in time order, ``values`` theirs) go left.
    Returns (qualities, left counts, right counts), each (C,). Each side's interest is
    :func:`interest` of its own values in time order (the same :func:`half_window` and
    :func:`window_interest`): its newest h values against the h before them, found by the members'
    rank from the newest, their signed sum taken in one pass. The same quantities as the
    per-candidate calls, summed in another order (the floats may differ in the last bits).

    Parameters
    ----------
    values : array_like, shape (N,)
        Values of the region's N points, in the order they were added.
    left : ndarray of bool, shape (N, C)
        ``left[i, c]``: point i goes left (to R1) under candidate c; C = number of candidates.
    zeta : int
        Interest window ζ of :func:`interest`.

    Returns
    -------
    quality : ndarray of float, shape (C,)
        :func:`split_quality` of each candidate.
    left_count : ndarray of int, shape (C,)
        card(R1) of each candidate.
    right_count : ndarray of int, shape (C,)
        card(R2) of each candidate.
    """
    values = np.asarray(values, dtype=float)
    n = len(values)
    nl = left.sum(axis=0)
    nr = n - nl
    rank_l = np.cumsum(left[::-1], axis=0)[::-1]              # left points at index >= t
    rank_r = np.arange(n, 0, -1)[:, None] - rank_l            # right points at index >= t
    hl, hr = half_window(nl, zeta), half_window(nr, zeta)
    # each point's rank from its side's newest (1 = newest) and its side's h
    rank = np.where(left, rank_l, rank_r)
    h = np.where(left, hl, hr)
    # +1: in the older half (h < rank <= 2h), -1: in the recent half (rank <= h), 0: outside
    w = (rank <= 2 * h).astype(float) - 2.0 * (rank <= h)
    # the windows' values only (a value outside them never enters a sum, as in interest())
    wv = np.where(w != 0.0, values[:, None] * w, 0.0)
    il = window_interest((wv * left).sum(axis=0), hl)
    ir = window_interest((wv * ~left).sum(axis=0), hr)
    quality = nl * nr * np.abs(il - ir)
    return quality, nl, nr


def choose_split(points: np.ndarray, values: np.ndarray, n_candidates: int, zeta: int,
                 rng: np.random.Generator) -> SplitChoice | None:
    """Pick the best of ``n_candidates`` random (dimension, value) splits (paper Sec. 2.4.4), by
    :func:`split_quality` (evaluated for all candidates at once by :func:`split_qualities`).

    Vague in the paper: how candidates are drawn and what happens when every candidate has quality 0
    (e.g. all competences equal). Choices: the dimension is uniform among dimensions whose points are
    not all equal; the value is uniform strictly between the smallest and largest point coordinate
    in that dimension (so both sides are non-empty); ties in quality (in particular all zero) are
    broken by the larger ``card(R1)·card(R2)`` (the most balanced split), then by candidate order.
    Points with coordinate ``< value`` go left, the others right. Returns None when no dimension can
    be split (all points identical). The candidates are drawn one after the other (dimension, then
    value) although their evaluation is batched: the same stream gives the same candidates as an
    evaluation one candidate at a time.

    Parameters
    ----------
    points : ndarray, shape (N, d)
        The region's N points (rows); d = the tree's dimension (m for the task space Y, 2n for
        ACTUATOR-RIAC's (α, Δα)).
    values : ndarray, shape (N,)
        Their values, in the order they were added.
    n_candidates : int
        Number of random candidates drawn (parameter ``split_candidates``), >= 1.
    zeta : int
        Interest window ζ of :func:`interest`.
    rng : numpy.random.Generator
        Stream the candidates are drawn from (the tree's split stream).

    Returns
    -------
    SplitChoice or None
        The best candidate: its dimension, value, quality and the two sides' point counts; None
        when every point is identical (nothing is drawn then).
    """
    lo = points.min(axis=0)
    hi = points.max(axis=0)
    dims = np.flatnonzero(hi > lo).tolist()
    if not dims:
        return None
    lo_l, hi_l = lo.tolist(), hi.tolist()
    js, vs = [], []
    for _ in range(n_candidates):
        j = dims[int(rng.integers(len(dims)))]
        v = float(rng.uniform(lo_l[j], hi_l[j]))
        if v <= lo_l[j]:  # uniform may return the lower end: keep both sides non-empty
            v = float(np.nextafter(lo_l[j], hi_l[j]))
        js.append(j)
        vs.append(v)
    quality, nl, nr = split_qualities(values, points[:, js] < np.array(vs), zeta)
    # the largest (quality, card(R1)·card(R2)), the first candidate among equals
    c = int(np.lexsort((-np.arange(n_candidates), nl * nr, quality))[-1])
    return SplitChoice(js[c], vs[c], float(quality[c]), int(nl[c]), int(nr[c]))


class RegionTree:
    """Recursive split of a box into regions; Algorithm 2 (UpdateRegions) of the paper.

    Parameters
    ----------
    lower, upper : array_like, shape (d,)
        Bounds of the root box, upper > lower in every dimension; d = the tree's dimension (m for
        the task space Y, 2n for ACTUATOR-RIAC's (α, Δα)).
    g_max : int
        Most points a region holds: one more splits it (Sec. 2.4.4), >= 2.
    zeta : int
        Interest window ζ (Sec. 2.4.3), >= 2.
    n_candidates : int
        Random split candidates per split (:func:`choose_split`), >= 1.
    rng : numpy.random.Generator
        Stream of the split candidates.

    Raises
    ------
    ValueError
        Bounds of unequal length, not 1-D or not increasing, or a parameter out of its range.
    """

    def __init__(self, lower, upper, g_max: int, zeta: int, n_candidates: int,
                 rng: np.random.Generator):
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        if self.lower.shape != self.upper.shape or self.lower.ndim != 1:
            raise ValueError("region tree bounds: lower and upper must be 1-D of equal length")
        if not np.all(self.upper > self.lower):
            raise ValueError(f"region tree bounds: upper {self.upper} must exceed lower {self.lower}")
        if g_max < 2:
            raise ValueError(f"g_max: got {g_max}; allowed: an integer >= 2")
        if zeta < 2:
            raise ValueError(f"zeta: got {zeta}; allowed: an integer >= 2")
        if n_candidates < 1:
            raise ValueError(f"split_candidates: got {n_candidates}; allowed: an integer >= 1")
        self.dim = len(self.lower)
        self._lower_list = self.lower.tolist()
        self._upper_list = self.upper.tolist()
        self.g_max = g_max
        self.zeta = zeta
        self.n_candidates = n_candidates
        self.rng = rng
        self._next_id = 0
        self.root = self._new_region(self.lower.copy(), self.upper.copy())
        self._leaves: list[Region] = [self.root]
        self.splits: list[dict] = []  # history: one dict per split
        self.n_added = 0
        self._interests = LeafInterests(self)  # the read path of interests()

    def _new_region(self, lower, upper, cap: int = 8) -> Region:
        r = Region(self._next_id, lower, upper, np.empty((cap, self.dim)), np.empty(cap),
                   zeta=self.zeta)
        self._next_id += 1
        return r

    def inside(self, y) -> bool:
        """Whether ``y`` is a point of the tree's space inside the root box (faces included).

        Parameters
        ----------
        y : array_like
            A candidate point; anything not of shape (d,) (d = the tree's dimension) is outside.

        Returns
        -------
        bool
            True when ``y`` has shape (d,) and ``lower <= y <= upper`` in every dimension.
        """
        y = np.asarray(y, dtype=float)
        return y.shape == (self.dim,) and self._inside_list(y.tolist())

    def _inside_list(self, yl: list[float]) -> bool:
        return all(lo <= v <= hi for lo, v, hi in zip(self._lower_list, yl, self._upper_list))

    def find(self, y) -> Region:
        """The leaf containing ``y`` (``y`` must be inside the root box).

        Parameters
        ----------
        y : array_like, shape (d,)
            A point inside the root box (d = the tree's dimension).

        Returns
        -------
        Region
            The leaf whose box holds ``y``; a point on a split face belongs to the upper child.
        """
        return self._find_list(y.tolist() if isinstance(y, np.ndarray) else list(y))

    def _find_list(self, yl: list[float]) -> Region:
        r = self.root
        while r.children is not None:
            r = r.children[0] if yl[r.split_dim] < r.split_value else r.children[1]
        return r

    def leaves(self) -> list[Region]:
        """The current leaves: the regions goals are chosen among.

        Returns
        -------
        list of Region, length L
            The tree's own list (not a copy), in the order of :meth:`interests`: a split puts the
            two children in the place of their parent.
        """
        return self._leaves

    def add(self, y, value: float, stamp: int | None = None) -> Region | None:
        """UpdateRegions(R, y, value): add, recompute the leaf's interest, split above g_max.

        Points outside the root box are ignored (returns None). ``stamp`` (e.g. the number of
        goals so far) is recorded with any split it causes, for the split-history figures.

        Parameters
        ----------
        y : array_like, shape (d,)
            The point: a goal, subgoal or reached position in Y, or an (α, Δα) pair for
            ACTUATOR-RIAC (d = the tree's dimension).
        value : float
            Its value: competence Γ, or minus the prediction error.
        stamp : int, optional
            Recorded with a split this point causes (None: no stamp).

        Returns
        -------
        Region or None
            The leaf the point was added to (when it caused a split, that region is now the parent
            of the two new leaves); None when ``y`` is outside the root box or not of shape (d,).
        """
        y = np.asarray(y, dtype=float)
        if y.shape != (self.dim,):
            return None
        yl = y.tolist()  # (inside and find on one list: a call per report)
        if not self._inside_list(yl):
            return None
        leaf = self._find_list(yl)
        leaf.add(y, float(value))
        self._interests.touched(leaf)
        self.n_added += 1
        if leaf.count > self.g_max:
            self._split(leaf, stamp)
        return leaf

    def _split(self, region: Region, stamp: int | None) -> None:
        pts, vals = region.filled_points, region.filled_values
        choice = choose_split(pts, vals, self.n_candidates, self.zeta, self.rng)
        if choice is None:
            return
        j, v = choice.dim, choice.value
        mask = pts[:, j] < v
        lu = region.upper.copy()
        lu[j] = v
        rl = region.lower.copy()
        rl[j] = v
        left = self._new_region(region.lower.copy(), lu, cap=max(8, int(mask.sum()) * 2))
        right = self._new_region(rl, region.upper.copy(), cap=max(8, int((~mask).sum()) * 2))
        for child, m in ((left, mask), (right, ~mask)):
            n = int(m.sum())
            child.points[:n] = pts[m]
            child.values[:n] = vals[m]
            child.count = n
            child._dirty = True
        region.children = (left, right)
        region.split_dim, region.split_value = j, v
        # free the parent's storage: the children hold its points
        region.points = np.empty((0, self.dim))
        region.values = np.empty(0)
        idx = self._leaves.index(region)  # by identity (Region compares by identity)
        self._leaves[idx:idx + 1] = [left, right]
        self._interests.split(region, left, right)
        self.splits.append({"stamp": stamp, "region": region.id, "dim": j, "value": v,
                            "quality": choice.quality, "left": left.id, "right": right.id,
                            "left_lower": left.lower.tolist(), "left_upper": left.upper.tolist(),
                            "right_lower": right.lower.tolist(), "right_upper": right.upper.tolist()})

    def interests(self) -> np.ndarray:
        """``np.array([r.interest for r in self.leaves()])``, kept up to date leaf by leaf
        (:mod:`sagg_common.leaf_interests`).

        Returns
        -------
        ndarray, shape (L,)
            Interest of each of the L leaves, in :meth:`leaves` order (a fresh array).
        """
        return self._interests.get()

    def snapshot(self) -> list[dict]:
        """The leaves as JSON-able dicts (bounds, interest, count, mean value).

        Returns
        -------
        list of dict, length L
            One dict per leaf, in :meth:`leaves` order: ``id``, ``lower`` and ``upper`` (lists of d
            floats), ``interest``, ``count`` and ``mean_competence`` (:meth:`Region.mean_value`).
        """
        return [{"id": r.id, "lower": r.lower.tolist(), "upper": r.upper.tolist(),
                 "interest": r.interest, "count": r.count, "mean_competence": r.mean_value()}
                for r in self._leaves]
