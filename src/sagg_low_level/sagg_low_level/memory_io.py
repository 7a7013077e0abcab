"""Persistence of the sample memory: its digest and its .npz file (no pickle), written atomically.

The file holds the construction parameters (int64 ``params``, float64 ``float_params``), the three
sample arrays and the digest; loading checks shapes, finiteness and the digest, then rebuilds the
index exactly as incremental adds would have left it. Format version 2 (+ checks, beam_ratio);
version-1 files load as exact memories.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

from .memory_index import LEAF_ORDERS as _LEAF_ORDERS

_FORMAT_VERSION = 2  # 2: + checks, beam_ratio (version-1 files load as exact memories)
_DIGEST_TAG = b"sagg.SampleMemory/v1"


def memory_digest(mem) -> str:
    """sha256 hex over the dims, the length and the filled arrays (little-endian float64, C order)."""
    h = hashlib.sha256(_DIGEST_TAG)
    h.update(np.array([mem._sd, mem._ad, mem._od, mem._n], dtype="<i8").tobytes())
    for arr in (mem._alpha, mem._dalpha, mem._dy):
        h.update(np.ascontiguousarray(arr[: mem._n], dtype="<f8").data)
    return h.hexdigest()


def params_array(mem) -> np.ndarray:
    """The int64 construction parameters written to the file (``params``), format version first."""
    return np.array(
        [
            _FORMAT_VERSION,
            mem._sd,
            mem._ad,
            mem._od,
            mem._buf,
            mem._leaf,
            mem._fan,
            mem._max_roots,
            mem._split_sample,
            mem._refine_nodes,
            mem._refine_leaves,
            _LEAF_ORDERS.index(mem._leaf_order),
            mem._tune_k,
            mem._cache_max,
            mem._checks,
        ],
        dtype=np.int64,
    )


def save_memory(mem, path) -> None:
    """Atomically write an .npz (no pickle): <path>.tmp.npz, then os.replace onto ``path``."""
    path = os.fspath(path)
    tmp = path + ".tmp.npz"
    with open(tmp, "wb") as fh:
        np.savez(
            fh,
            params=params_array(mem),
            float_params=np.array([mem._cache_expand, mem._cache_scan, mem._beam_ratio]),
            alpha=mem._alpha[: mem._n],
            delta_alpha=mem._dalpha[: mem._n],
            delta_y=mem._dy[: mem._n],
            digest=np.array(memory_digest(mem)),
        )
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _read_file(path) -> tuple[tuple[int, ...], np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray], str]:
    """The checked content of a file written by :func:`save_memory`: the int construction
    parameters (format version first, version 1 extended to version 2), the float ones, the three
    sample arrays (float64, finite, of the file's dimensions) and the digest. ValueError otherwise."""
    with np.load(os.fspath(path), allow_pickle=False) as z:
        missing = {"params", "float_params", "alpha", "delta_alpha", "delta_y", "digest"} - set(z.files)
        if missing:
            raise ValueError(f"path is not a SampleMemory file: missing {sorted(missing)}")
        params = z["params"]
        fparams = z["float_params"]
        alpha, dalpha, dy = z["alpha"], z["delta_alpha"], z["delta_y"]
        digest = str(z["digest"])
    version = int(params[0]) if params.ndim == 1 and len(params) else -1
    if version == 1 and params.shape == (14,) and fparams.shape == (2,):
        params = np.append(params, 0)  # version 1: exact search only
        fparams = np.append(fparams, 0.5)
    elif version != _FORMAT_VERSION or params.shape != (15,) or fparams.shape != (3,):
        raise ValueError(f"path has an unsupported SampleMemory format (params {params.tolist()})")
    ints = tuple(int(v) for v in params)
    sd, ad, od = ints[1:4]
    n = alpha.shape[0]
    for name, arr, dim in (("alpha", alpha, sd), ("delta_alpha", dalpha, ad), ("delta_y", dy, od)):
        if arr.dtype != np.float64 or arr.shape != (n, dim):
            raise ValueError(f"{name} in file must be float64 of shape ({n}, {dim}), got {arr.dtype} {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} in file must be finite")
    return ints, fparams, (alpha, dalpha, dy), digest


def _fill(store, rows: tuple[np.ndarray, np.ndarray, np.ndarray], digest: str) -> None:
    """Put the checked ``rows`` into an empty ``store`` of their capacity; ValueError when the
    file's digest does not match them."""
    n = rows[0].shape[0]
    store._alpha[:n], store._dalpha[:n], store._dy[:n] = rows
    store._n = n
    if store.digest() != digest:
        raise ValueError("file digest does not match its content (corrupted file)")


def load_memory(cls, path):
    """Read a file written by :func:`save_memory` into a new ``cls`` (SampleMemory); the index is
    rebuilt exactly as it was."""
    ints, fparams, rows, digest = _read_file(path)
    _, sd, ad, od, buf, leaf, fan, roots, split, refine, rleaves, order, tune_k, cmax, checks = ints
    if not 0 <= order < len(_LEAF_ORDERS):
        raise ValueError(f"path has an unknown leaf_order code {order}")
    mem = cls(
        sd, ad, od, capacity=max(1, rows[0].shape[0]), buffer_size=buf, leaf_size=leaf, fanout=fan,
        max_roots=roots, split_sample=split, refine_nodes=refine, refine_leaves=rleaves,
        leaf_order=_LEAF_ORDERS[order], tune_k=tune_k, cache_expand=float(fparams[0]),
        cache_scan=float(fparams[1]), cache_max=cmax, checks=checks, beam_ratio=float(fparams[2]),
    )
    _fill(mem, rows, digest)
    mem._rebuild_all()
    return mem


def load_table(cls, path):
    """Read the samples of a file written by :func:`save_memory` into a new ``cls``
    (SampleTable: the rows without a search index), checked as :func:`load_memory` checks them."""
    ints, _, rows, digest = _read_file(path)
    table = cls(*ints[1:4], capacity=max(1, rows[0].shape[0]))
    _fill(table, rows, digest)
    return table
