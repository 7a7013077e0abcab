"""Samples of another run as the learner's prior, and the rule by which the robot's own samples
supersede them. ROS-free.

A robot run can start from what a simulation of the same robot learned (``sagg run CONFIG
--driver external --prior RUN_DIR``): the simulated run's samples (α, Δα, Δy) become this run's
*prior*. The robot's own samples stay in the learner's :class:`~sagg_low_level.memory.SampleMemory`
(whose rows are this run's micro-actions, as without a prior: the bag, the checkpoints and the
sample numbering are unchanged); the prior is a second, fixed store beside it. The local model at
α (Sec. 3.3: the least-squares Jacobian of the k samples nearest to α) is fitted from the k
nearest among the robot's samples and the prior samples still in use.

The precedence rule (our choice; the paper has no prior): prior sample i is *superseded*, and never
used again, once a robot sample lies within ``radius`` of it in α (Euclidean, in rad: the space the
local models' neighbours are found in). Where the robot has been, its own samples describe the arm
(a real arm differs from its model: calibration, link tolerances); where it has not, the simulation
still does. The default radius (``prior.radius`` 0) is the length of the largest exploratory
micro-action, ``explore_amplitude`` × √n: a robot sample that close to a prior sample lies in the
neighbourhood one exploration of that prior posture would probe. Ties in the merged neighbour list
put the robot's sample first.

The rule is a function of the stored samples only (not of the order the robot's samples came in):
:meth:`Prior.cover_all` after a restore gives the same superseded set as :meth:`Prior.cover` after
every sample.
"""
from __future__ import annotations

import math

import numpy as np

from sagg_common.params import ConfigError

from .memory import SampleTable
from .memory_distance import squared_distances

__all__ = ["Prior", "default_radius", "load_prior", "merged_neighbours", "neighbour_rows"]


def default_radius(explore_amplitude: float, n: int) -> float:
    """The default supersession radius: the length of the largest exploratory micro-action,
    ``explore_amplitude`` × √n (rad).

    Parameters
    ----------
    explore_amplitude : float
        a, the exploration's uniform bound per joint (rad).
    n : int
        Joints.

    Returns
    -------
    float
        a·√n.
    """
    return float(explore_amplitude) * math.sqrt(n)


class Prior:
    """The prior samples of a run: fixed rows (α, Δα, Δy), a search tree over their α, and which
    of them robot samples have superseded (the module's rule).

    Parameters
    ----------
    alpha, delta_alpha : ndarray, shape (P, n)
        The prior samples' postures and joint displacements; n = joints.
    delta_y : ndarray, shape (P, m)
        Their effector displacements; m = task dimensions.
    radius : float
        The supersession radius (rad), > 0.
    source : str
        Where the samples came from (said in summaries).

    Raises
    ------
    ValueError
        Arrays of unequal lengths or wrong ranks, non-finite values, no sample, a radius <= 0.
    """

    def __init__(self, alpha: np.ndarray, delta_alpha: np.ndarray, delta_y: np.ndarray, radius: float,
                 source: str = ""):
        a, da, dy = (np.array(x, dtype=float) for x in (alpha, delta_alpha, delta_y))
        if a.ndim != 2 or da.shape != a.shape or dy.ndim != 2 or len(dy) != len(a) or not len(a):
            raise ValueError(f"prior samples: alpha {a.shape}, delta_alpha {da.shape} and delta_y {dy.shape}; "
                             "allowed: (P, n), (P, n) and (P, m) with P >= 1")
        if not (np.isfinite(a).all() and np.isfinite(da).all() and np.isfinite(dy).all()):
            raise ValueError("prior samples: non-finite values (NaN/inf)")
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"prior.radius: got {radius!r}; allowed: a finite number > 0 (rad)")
        for x in (a, da, dy):
            x.flags.writeable = False
        self.alpha, self.delta_alpha, self.delta_y = a, da, dy
        self.radius = float(radius)
        self.source = source
        # lazy (heavy): scipy (only a run with a prior needs it; the learner imports this module)
        from scipy.spatial import cKDTree
        self._tree = cKDTree(a)
        self.superseded = np.zeros(len(a), dtype=bool)
        self.superseded_count = 0

    def __len__(self) -> int:
        return len(self.alpha)

    @property
    def live_count(self) -> int:
        """Prior samples still used."""
        return len(self.alpha) - self.superseded_count

    # ------------------------------------------------------------------ the precedence rule
    def cover(self, alpha: np.ndarray) -> int:
        """A robot sample at ``alpha`` supersedes every prior sample within :attr:`radius`.

        Parameters
        ----------
        alpha : ndarray, shape (n,)
            The robot sample's posture.

        Returns
        -------
        int
            How many prior samples it newly superseded.
        """
        hit = np.asarray(self._tree.query_ball_point(alpha, self.radius), dtype=np.int64)
        new = hit[~self.superseded[hit]] if len(hit) else hit
        self.superseded[new] = True
        self.superseded_count += len(new)
        return len(new)

    def cover_all(self, robot_alpha: np.ndarray) -> None:
        """The superseded set from all the robot's samples at once (after a restore): the same set
        :meth:`cover` leaves after each of them.

        Parameters
        ----------
        robot_alpha : ndarray, shape (N, n)
            The robot samples' postures.
        """
        self.superseded[:] = False
        if len(robot_alpha):
            # lazy (heavy): scipy
            from scipy.spatial import cKDTree
            near = cKDTree(np.asarray(robot_alpha, dtype=float)).query_ball_point(self.alpha, self.radius,
                                                                                    return_length=True)
            self.superseded[:] = np.asarray(near) > 0
        self.superseded_count = int(self.superseded.sum())

    # ------------------------------------------------------------------ neighbours
    def nearest_live(self, query: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` prior samples nearest to ``query`` that are not superseded (fewer when fewer
        are left), by (squared distance, index).

        Parameters
        ----------
        query : ndarray, shape (n,)
        k : int

        Returns
        -------
        idx : ndarray of int, shape (k',)
            Prior rows, nearest first.
        sq : ndarray, shape (k',)
            Their squared distances (the memory's canonical sum, :mod:`.memory_distance`).
        """
        want = min(k, self.live_count)
        if want <= 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        kk = min(len(self.alpha), 2 * want)
        while True:  # widen until enough of the nearest are still in use
            _, idx = self._tree.query(query, k=kk)
            idx = np.atleast_1d(idx)
            live = idx[~self.superseded[idx]]
            if len(live) >= want or kk == len(self.alpha):
                break
            kk = min(len(self.alpha), 4 * kk)
        # ordered by the memory's own distance (the tree's float sums may differ in the last bit)
        sq = squared_distances(self.alpha[live], query)
        order = np.lexsort((live, sq))[:want]
        return live[order], sq[order]


def merged_neighbours(mem, prior: Prior, query: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k samples nearest to ``query`` among the robot's (``mem``) and the prior's still in use:
    (rows of ``mem``, rows of ``prior``), by squared distance, the robot's first on a tie.

    Parameters
    ----------
    mem : SampleMemory
        The robot's samples.
    prior : Prior
    query : ndarray, shape (n,)
    k : int

    Returns
    -------
    robot_idx, prior_idx : ndarray of int
        Together at most k rows.
    """
    r = mem.neighbours(query, k) if len(mem) else np.zeros(0, dtype=np.int64)
    p, psq = prior.nearest_live(query, k)
    if not len(p):
        return r, p
    rsq = squared_distances(mem.alpha[r], query) if len(r) else np.zeros(0)
    dist = np.concatenate((rsq, psq))
    origin = np.concatenate((np.zeros(len(r), dtype=np.int64), np.ones(len(p), dtype=np.int64)))
    rank = np.concatenate((np.arange(len(r)), np.arange(len(p))))
    keep = np.lexsort((rank, origin, dist))[:k]
    robot = keep[origin[keep] == 0]
    return r[rank[robot]], p[rank[keep[origin[keep] == 1]]]


def neighbour_rows(mem, prior: Prior, query: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, bytes]:
    """The (Δα, Δy) rows of :func:`merged_neighbours` and a key naming the set (equal sets, equal
    keys): what the local model is fitted from.

    Returns
    -------
    delta_alpha : ndarray, shape (k', n)
    delta_y : ndarray, shape (k', m)
    key : bytes
    """
    r, p = merged_neighbours(mem, prior, query, k)
    da = np.concatenate((mem.delta_alpha[r], prior.delta_alpha[p]))
    dy = np.concatenate((mem.delta_y[r], prior.delta_y[p]))
    return da, dy, r.tobytes() + b"|" + p.tobytes()


def load_prior(params: dict, n: int, m: int) -> Prior:
    """The prior of the learner parameters ``prior.memory`` (a sample memory file, as
    :meth:`SampleMemory.save <sagg_low_level.memory.SampleMemory.save>` writes it) and
    ``prior.radius`` (0: :func:`default_radius`).

    Parameters
    ----------
    params : dict
        The learner's parameters.
    n, m : int
        The learner's joints and task dimensions: the file's samples must have them.

    Returns
    -------
    Prior

    Raises
    ------
    ConfigError
        The file cannot be read, holds no sample, or its dimensions differ; names the parameter.
    """
    path = params["prior.memory"]
    try:
        mem = SampleTable.load(path)
    except (OSError, ValueError, KeyError) as exc:
        raise ConfigError(f"parameter 'prior.memory': {path!r}: {exc}") from exc
    if (mem.state_dim, mem.outcome_dim) != (n, m) or not len(mem):
        raise ConfigError(f"parameter 'prior.memory': {path!r} holds {len(mem)} samples of {mem.state_dim} "
                          f"joints and {mem.outcome_dim} task dimensions; allowed: >= 1 sample of {n} joints "
                          f"and {m} task dimensions (this robot's)")
    radius = params.get("prior.radius", 0.0) or default_radius(params["explore_amplitude"], n)
    return Prior(mem.alpha, mem.delta_alpha, mem.delta_y, radius, source=str(path))
