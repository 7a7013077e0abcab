"""Sample memory of the evolving-context learner with k-nearest-neighbour search on alpha.

Paper Sec. 3.3 ("Representation of Forward and Inverse Models to be Learnt"): every micro-action
stores (alpha, delta_alpha, delta_y) and, at every micro-action, the learner needs the k nearest stored
alpha to the current alpha to fit a local Jacobian. The paper uses an incremental *approximate*
nearest-neighbour index (FLANN, "Muja09"). Two modes:

* exact (``checks=0``): the EXACT k nearest, a deterministic function of the stored samples (ties
  broken by index), independent of how the index is built, identical after save/load. Its cost
  grows with the memory (in 15 dims the k-NN ball meets a large share of the leaves).
* approximate (``checks > 0``, as in the paper): a bounded best-bin-first search in FLANN's sense
  ("checks"): at most ``checks`` leaves of the index are scanned per query (plus the buffer), so the
  cost per query stays flat as the memory grows. Results are real stored samples with their exact
  distances, sorted by (distance, index); they are a deterministic function of the stored samples
  (in insertion order), the query and k: NOT of earlier queries (the trajectory cache below is
  not used, so evaluation queries interleaved with learning cannot change what the learner
  gets), of timing, or of save/load. When the budget covers every leaf the search needs, the
  answer is the exact one. See :meth:`SampleMemory._knn_approx`.

Design (measured with ``python -m sagg_lab.memory_bench``; numbers in the commit messages):

* Samples live in preallocated float64 arrays that double their capacity (amortised O(1) add).
  Storage: :mod:`sagg_low_level.memory_store`.
* Index (:mod:`sagg_low_level.memory_index`): a logarithmic method (Bentley-Saxe) of static blocks
  of kd or time-ordered leaves under bounding boxes, plus a brute-force buffer of the newest samples;
  exact duplicates of alpha (the rest posture) stored once per block.
* Search (:mod:`sagg_low_level.memory_search`): exact or approximate (``checks``) k nearest over the
  index, and the trajectory cache of the exact mode.
* Persistence (:mod:`sagg_low_level.memory_io`): digest, atomic .npz save (no pickle), load with the
  index rebuilt exactly.
* Distances (:mod:`sagg_low_level.memory_distance`): squared Euclidean distances in float64, summed
  over coordinates in index order, bit-identical whichever path found the point; the order of
  results is by (that distance, sample index).
* Why not scipy's cKDTree: one ``cKDTree.query`` has a large fixed cost even on a tiny tree (Python
  argument handling), a logarithmic forest needs one call per tree, and its k-th-neighbour ties are
  not broken by index (a forest of cKDTrees measured no faster: ``memory_bench --ckdtree``).

This module holds the class callers use: it checks the construction parameters, owns the public
API and composes the parts above (one object: each part module is a mixin owning its own state).
"""

from __future__ import annotations

import math

import numpy as np

from sagg_common.diagnostics import all_finite

# _sqdist_cols is also imported from here by the memory benchmark
from .memory_distance import _sqdist_cols, squared_distances  # noqa: F401
from .memory_index import LEAF_ORDERS as _LEAF_ORDERS, BlockIndex
from .memory_io import load_memory, load_table, params_array, save_memory
from .memory_search import KnnSearch
from .memory_store import SampleStore

__all__ = ["SampleMemory", "SampleTable", "squared_distances"]


def _is_pow2(x: int) -> bool:
    return x >= 1 and (x & (x - 1)) == 0


def _check_int(name: str, value, low: int, high: int | None = None) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer in [{low}, {high if high is not None else 'inf'}], got {value!r}")
    value = int(value)
    if value < low or (high is not None and value > high):
        raise ValueError(f"{name} must be an integer in [{low}, {high if high is not None else 'inf'}], got {value}")
    return value



def _init_dims(mem, state_dim, action_dim, outcome_dim, capacity) -> int:
    """Check and set the dimensions of a memory; return the checked capacity."""
    mem._sd = _check_int("state_dim", state_dim, 1)
    mem._ad = _check_int("action_dim", action_dim, 1)
    mem._od = _check_int("outcome_dim", outcome_dim, 1)
    return _check_int("capacity", capacity, 1)


class SampleMemory(SampleStore, BlockIndex, KnnSearch):
    """Growing store of (alpha, delta_alpha, delta_y) with exact k-NN queries on alpha.

    Parameters (the paper gives none of these; they only trade speed and memory, never results):
      capacity     initial number of rows allocated (doubles when full), >= 1.
      buffer_size  B: the brute-force buffer holds the newest B..2B-1 samples once 2B were added;
                   must be leaf_size * 2**j. Smaller B = cheaper buffer scan, more rebuild work.
      leaf_size    points per kd leaf (power of two >= 2).
      fanout       children per box node (power of two >= 2).
      max_roots    a block grows box heights until it has at most this many top nodes (>= 1).
      split_sample points sampled per segment to pick the kd split coordinate (>= 2).
      refine_nodes when a query's first bound keeps more than this many nodes at some height, a
                   greedy descent to the refine_leaves most promising leaves computes a tighter
                   bound first (>= 1); speed only.
      refine_leaves leaves scanned by that descent (>= 1; at least ceil(k / leaf_size) + 1 are used).
      leaf_order   how a block groups its samples into leaves: "kd" (balanced kd partition: best when
                   samples are dense relative to the query radius, e.g. n = 7 or uniform data),
                   "time" (consecutive samples: best for trajectories in 15-30 dims, where a kd tree
                   splits each coordinate at most once), or "auto" (per block, the one whose leaves
                   meet fewer exact tune_k-NN balls of sample queries drawn from the block).
      tune_k       k used by "auto" (default 2 * state_dim + 2).
      cache_expand consecutive queries along a trajectory: a query that walks the index also keeps
                   every sample within cache_expand times (an upper bound of) its k-th distance;
                   later queries are answered from that cache alone while the triangle inequality
                   proves it holds their k nearest (0 disables; otherwise in (1, 16]).
      cache_scan   the wider walk scans at most cache_scan times the leaves the answer needs; the
                   cache radius is cut to what those leaves cover (in [1, 1e6]).
      cache_max    the cache is shrunk to about this many samples (>= 1).
      checks       0 = exact search. > 0 = approximate search as in the paper (Sec. 3.3, FLANN's
                   "checks"): at most this many leaves (of leaf_size samples) are scanned per query,
                   besides the buffer and the leaves holding exact copies of the query; in [0, 2**31].
                   Changes results (not only speed); the trajectory cache is not used.
      beam_ratio   approximate search: at box height h >= 1 at most ceil(checks * beam_ratio**h)
                   nodes are kept (those of smallest box distance); in (0, 1].
    """

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        outcome_dim: int,
        capacity: int = 1024,
        buffer_size: int = 256,
        *,
        leaf_size: int = 32,
        fanout: int = 16,
        max_roots: int = 64,
        split_sample: int = 16,
        refine_nodes: int = 64,
        refine_leaves: int = 16,
        leaf_order: str = "auto",
        tune_k: int | None = None,
        cache_expand: float = 1.6,
        cache_scan: float = 4.0,
        cache_max: int = 4096,
        checks: int = 0,
        beam_ratio: float = 0.5,
    ):
        cap = _init_dims(self, state_dim, action_dim, outcome_dim, capacity)
        self._leaf = _check_int("leaf_size", leaf_size, 2)
        if not _is_pow2(self._leaf):
            raise ValueError(f"leaf_size must be a power of two >= 2, got {leaf_size}")
        self._fan = _check_int("fanout", fanout, 2)
        if not _is_pow2(self._fan):
            raise ValueError(f"fanout must be a power of two >= 2, got {fanout}")
        self._buf = _check_int("buffer_size", buffer_size, self._leaf)
        if self._buf % self._leaf or not _is_pow2(self._buf // self._leaf):
            raise ValueError(
                f"buffer_size must be leaf_size * 2**j (leaf_size={self._leaf}), got {buffer_size}"
            )
        self._max_roots = _check_int("max_roots", max_roots, 1)
        self._split_sample = _check_int("split_sample", split_sample, 2)
        self._refine_nodes = _check_int("refine_nodes", refine_nodes, 1)
        self._refine_leaves = _check_int("refine_leaves", refine_leaves, 1)
        if leaf_order not in _LEAF_ORDERS:
            raise ValueError(f"leaf_order must be one of {_LEAF_ORDERS}, got {leaf_order!r}")
        self._leaf_order = leaf_order
        # k the 'auto' leaf order is tuned for; default 2n + 2 (see memory_bench.default_k)
        self._tune_k = _check_int("tune_k", 2 * self._sd + 2 if tune_k is None else tune_k, 1)
        if isinstance(cache_expand, bool) or not isinstance(cache_expand, (int, float, np.floating)) \
                or not (cache_expand == 0 or 1.0 < cache_expand <= 16.0):
            raise ValueError(f"cache_expand must be 0 (no cache) or in (1, 16], got {cache_expand!r}")
        self._cache_expand = float(cache_expand)
        if isinstance(cache_scan, bool) or not isinstance(cache_scan, (int, float, np.floating)) \
                or not 1.0 <= cache_scan <= 1e6:
            raise ValueError(f"cache_scan must be in [1, 1e6], got {cache_scan!r}")
        self._cache_scan = float(cache_scan)
        self._cache_max = _check_int("cache_max", cache_max, 1)
        self._checks = _check_int("checks", checks, 0, 2**31)
        if isinstance(beam_ratio, bool) or not isinstance(beam_ratio, (int, float, np.floating)) \
                or not 0.0 < beam_ratio <= 1.0:
            raise ValueError(f"beam_ratio must be in (0, 1], got {beam_ratio!r}")
        self._beam_ratio = float(beam_ratio)
        # approximate search: nodes kept per box height (0 = leaves; heights stay far below 64)
        self._widths = np.array([max(1, math.ceil(self._checks * self._beam_ratio**h)) for h in range(64)],
                                dtype=np.int64)

        self._init_store(cap)
        self._init_index()
        self._init_search()

    def add(self, alpha, delta_alpha, delta_y) -> int:
        """Store one sample; return its index. Raises ValueError on wrong shapes or non-finite values."""
        i, a = self._append(alpha, delta_alpha, delta_y)
        self._cache_add(i, a)
        self._buffer_add(i, a)
        return i

    @property
    def nbytes(self) -> int:
        """Bytes held by the sample arrays and the index (allocated capacity included)."""
        total = self._alpha.nbytes + self._dalpha.nbytes + self._dy.nbytes + self._buf_t.nbytes
        total += self._pts.nbytes + self._pidx.nbytes + sum(b.nbytes for b in self._boxes)
        total += self._cache_t.nbytes + self._cache_i.nbytes + self._dup.nbytes + self._dup_off.nbytes
        return int(total)

    # ------------------------------------------------------------------ queries
    def _query_vector(self, query) -> np.ndarray:
        q = self._vector("query", query, self._sd)
        if not all_finite(q):
            raise ValueError(f"query must be finite (no NaN/inf), got {q}")
        return q

    def _check_k(self, k) -> int:
        return _check_int("k", k, 1)

    def neighbours(self, query: np.ndarray, k: int) -> np.ndarray:
        """Indices of the min(k, len) stored alpha nearest to ``query``, by (distance, index)."""
        q = self._query_vector(query)
        k = self._check_k(k)
        return self._knn(q, k)

    def neighbours_batch(self, queries: np.ndarray, k: int) -> np.ndarray:
        """(B, min(k, len)) array: row i is ``neighbours(queries[i], k)``."""
        try:
            qs = np.asarray(queries, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"queries must be a finite float array of shape (B, {self._sd}): {exc}") from None
        if qs.ndim != 2 or qs.shape[1] != self._sd:
            raise ValueError(f"queries must have shape (B, {self._sd}), got {qs.shape}")
        if not np.isfinite(qs).all():
            raise ValueError("queries must be finite (no NaN/inf)")
        k = self._check_k(k)
        out = np.empty((qs.shape[0], min(k, self._n)), dtype=np.int64)
        for i in range(qs.shape[0]):
            out[i] = self._knn(qs[i], k)
        return out

    # ------------------------------------------------------------------ persistence
    def _params(self) -> np.ndarray:
        return params_array(self)

    def save(self, path) -> None:
        """Atomically write an .npz (no pickle): <path>.tmp.npz, then os.replace onto ``path``."""
        save_memory(self, path)

    @classmethod
    def load(cls, path) -> "SampleMemory":
        """Read a file written by :meth:`save`; the index is rebuilt exactly as it was."""
        return load_memory(cls, path)


class SampleTable(SampleStore):
    """The rows of a :class:`SampleMemory` without its search index: the same storage, views and
    digest (the same samples give the same :meth:`digest`), for a caller that searches them with its
    own index (the fixed-context learner's :class:`~sagg_low_level.tree_knn.TreeKnn`), so that no
    index is kept up to date for nothing."""

    def __init__(self, state_dim: int, action_dim: int, outcome_dim: int, capacity: int = 1024):
        self._init_store(_init_dims(self, state_dim, action_dim, outcome_dim, capacity))

    def add(self, alpha, delta_alpha, delta_y) -> int:
        """Store one sample; return its index. Raises ValueError on wrong shapes or non-finite values."""
        return self._append(alpha, delta_alpha, delta_y)[0]

    @classmethod
    def load(cls, path) -> "SampleTable":
        """The samples of a :meth:`SampleMemory.save` file, checked as :meth:`SampleMemory.load`
        checks them, without building its index (a caller that only reads the rows)."""
        return load_table(cls, path)

    @property
    def nbytes(self) -> int:
        """Bytes held by the sample arrays (allocated capacity included)."""
        return int(self._alpha.nbytes + self._dalpha.nbytes + self._dy.nbytes)
