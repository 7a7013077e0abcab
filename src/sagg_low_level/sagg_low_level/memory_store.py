"""Storage of the sample memory: the (alpha, delta_alpha, delta_y) rows, checked on the way in.

A mixin of :class:`sagg_low_level.memory.SampleMemory` (one object; this module owns ``_alpha``,
``_dalpha``, ``_dy`` and the count ``_n``). Samples live in preallocated float64 arrays that double
their capacity (amortised O(1) add); readers get read-only views.
"""

from __future__ import annotations

import numpy as np

from .memory_io import memory_digest


class SampleStore:
    """The stored rows (mixin of SampleMemory)."""

    def _init_store(self, cap: int) -> None:
        self._n = 0  # number of samples
        self._alpha = np.empty((cap, self._sd))
        self._dalpha = np.empty((cap, self._ad))
        self._dy = np.empty((cap, self._od))

    def __len__(self) -> int:
        return self._n

    @property
    def state_dim(self) -> int:
        return self._sd

    @property
    def action_dim(self) -> int:
        return self._ad

    @property
    def outcome_dim(self) -> int:
        return self._od

    def digest(self) -> str:
        """sha256 hex over the dims, the length and the filled arrays (see memory_io.memory_digest):
        the same samples give the same digest in a SampleMemory and a SampleTable."""
        return memory_digest(self)

    def _view(self, arr: np.ndarray) -> np.ndarray:
        v = arr[: self._n].view()
        v.flags.writeable = False
        return v

    @property
    def alpha(self) -> np.ndarray:
        """Read-only (len, state_dim) view of the stored alpha."""
        return self._view(self._alpha)

    @property
    def delta_alpha(self) -> np.ndarray:
        """Read-only (len, action_dim) view of the stored delta_alpha."""
        return self._view(self._dalpha)

    @property
    def delta_y(self) -> np.ndarray:
        """Read-only (len, outcome_dim) view of the stored delta_y."""
        return self._view(self._dy)

    @staticmethod
    def _vector(name: str, value, dim: int) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a finite float vector of shape ({dim},): {exc}") from None
        if arr.shape != (dim,):
            raise ValueError(f"{name} must have shape ({dim},), got {arr.shape}")
        return arr

    def _append(self, alpha, delta_alpha, delta_y) -> tuple[int, np.ndarray]:
        """Store one sample; return its index and its alpha (float64). ValueError on wrong shapes or
        non-finite values (then nothing is stored)."""
        a = self._vector("alpha", alpha, self._sd)
        da = self._vector("delta_alpha", delta_alpha, self._ad)
        dy = self._vector("delta_y", delta_y, self._od)
        # x . x is finite unless some entry is inf/NaN (or |x| > 1e154): one cheap call per vector,
        # the exact check only when it is not (inf * inf and NaN * NaN raise no FP warning).
        if not a.dot(a) + da.dot(da) + dy.dot(dy) < np.inf:
            for name, v in (("alpha", a), ("delta_alpha", da), ("delta_y", dy)):
                if not np.isfinite(v).all():
                    raise ValueError(f"{name} must be finite (no NaN/inf), got {v}")
        i = self._n
        if i == self._alpha.shape[0]:
            self._grow(2 * i)
        self._alpha[i] = a
        self._dalpha[i] = da
        self._dy[i] = dy
        self._n = i + 1
        return i, a

    def _grow(self, cap: int) -> None:
        for name in ("_alpha", "_dalpha", "_dy"):
            old = getattr(self, name)
            new = np.empty((cap, old.shape[1]))
            new[: self._n] = old[: self._n]
            setattr(self, name, new)

