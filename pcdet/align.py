"""Closed-form rigid alignment of corresponding points: Kabsch (weighted, batched) and Umeyama (with scale).

The rotation of each Kabsch problem comes from a small compiled kernel (``pcdet/_align.c``: the quaternion of
Horn's 4 x 4 matrix, which releases the interpreter lock) where the install could build it, and from numpy's SVD
otherwise. Both give the optimal proper rotation and round differently: on well-posed problems their rotation
entries agree within 1e-12 (``tests/test_align.py``).
"""
from __future__ import annotations

import numpy as np

try:  # the compiled kernel, where the install could build it
    from . import _align
except ImportError:  # pragma: no cover - exercised where no compiler was at hand
    _align = None


def compiled() -> bool:
    """Whether the compiled kernel is in use (otherwise numpy's SVD gives the rotations)."""
    return _align is not None


def greedy_distinct(T: np.ndarray, order: np.ndarray, cos_min: float, near2: float, limit: int
                    ) -> np.ndarray | None:
    """The compiled greedy walk of ``grouping.common.distinct_poses``: the first ``limit`` entries of ``order``
    ((n,) indices into T (B, 4, 4)) whose pose is near no entry kept before it, near meaning (trace(Ra^T Rb) - 1) / 2
    > ``cos_min`` and |ta - tb|^2 < ``near2`` (m^2). (k,) int64, or None where the kernel is not built."""
    if _align is None:
        return None
    order = np.ascontiguousarray(order, dtype=np.int64)
    kept = np.empty(max(min(limit, len(order)), 0), np.int64)
    n = _align.distinct(np.ascontiguousarray(T, dtype=np.float64), order, float(cos_min), float(near2),
                        max(int(limit), 0), kept)
    return kept[:n]


def kabsch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Rigid ``T_dst_src`` (4, 4) minimising sum w ||R src + t - dst||^2; ``R`` is a proper rotation (det +1).

    src, dst : (N, 3) float, N >= 3 corresponding points; weights : (N,) non-negative or None.
    """
    return kabsch_batch(np.asarray(src, float)[None], np.asarray(dst, float)[None],
                        None if weights is None else np.asarray(weights, float)[None])[0]


def kabsch_batch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Kabsch for B problems at once: src, dst (B, N, 3), weights (B, N) -> (B, 4, 4)."""
    if src.shape != dst.shape or src.ndim != 3 or src.shape[2] != 3:
        raise ValueError(f"kabsch needs matching (B, N, 3) arrays, got {src.shape} and {dst.shape}")
    B, N, _ = src.shape
    w = np.ones((B, N)) if weights is None else weights
    wsum = w.sum(axis=1, keepdims=True)
    if np.any(wsum <= 0):
        raise ValueError("kabsch weights sum to zero")
    w = (w / wsum)[..., None]
    cs = (w * src).sum(axis=1)
    cd = (w * dst).sum(axis=1)
    H = np.matmul((src - cs[:, None]).transpose(0, 2, 1), w * (dst - cd[:, None]))  # (B, 3, 3)
    return _rigid_from_covariance(H, cs, cd)


def kabsch_shared(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Kabsch for B weightings of one correspondence set: src, dst (N, 3), weights (B, N) -> (B, 4, 4).

    Same result as ``kabsch_batch`` on broadcast copies, but the weighted sums are matrix products, so the
    cost is O(B N) multiply-adds instead of several (B, N, 3) temporaries.
    """
    w = np.asarray(weights, float)
    wsum = w.sum(axis=1)
    if np.any(wsum <= 0):
        raise ValueError("kabsch weights sum to zero")
    cs = (w @ src) / wsum[:, None]
    cd = (w @ dst) / wsum[:, None]
    # sum_i w_i (s_i - cs)(d_i - cd)^T = sum_i w_i s_i d_i^T - wsum cs cd^T
    H = np.einsum("bn,ni,nj->bij", w, src, dst, optimize=True) / wsum[:, None, None] \
        - cs[:, :, None] * cd[:, None, :]
    return _rigid_from_covariance(H, cs, cd)


def kabsch_from_sums(sums: np.ndarray) -> np.ndarray:
    """Kabsch from weighted sums: sums (B, 16) holding, for each problem, sum w, sum w src (3), sum w dst (3) and
    sum w src_i dst_j (9, row i) -> (B, 4, 4) ``T_dst_src``. The sum of the weights must be positive."""
    s = np.asarray(sums, float).reshape(-1, 16)
    wsum = s[:, 0]
    if np.any(wsum <= 0):
        raise ValueError("kabsch weights sum to zero")
    cs = s[:, 1:4] / wsum[:, None]
    cd = s[:, 4:7] / wsum[:, None]
    H = s[:, 7:].reshape(-1, 3, 3) / wsum[:, None, None] - cs[:, :, None] * cd[:, None, :]
    return _rigid_from_covariance(H, cs, cd)


def _rigid_from_covariance(H: np.ndarray, cs: np.ndarray, cd: np.ndarray, *, use_compiled: bool = True
                           ) -> np.ndarray:
    """(B, 4, 4) rigid transforms from B cross-covariances H (B, 3, 3) of centred source/target points and the
    centroids cs, cd (B, 3): the proper rotation R maximising trace(R H), and t = cd - R cs. In numpy, R = V
    diag(1, 1, d) U^T with d = sign det(V U^T), so never a reflection."""
    if use_compiled and _align is not None:
        H = np.ascontiguousarray(H, dtype=np.float64)
        if not np.isfinite(H).all():  # as numpy's SVD refuses them, so callers that catch LinAlgError still do
            raise np.linalg.LinAlgError("Kabsch: the cross-covariance holds NaN or infinity")
        T = np.empty((len(H), 4, 4))
        _align.rigid_from_covariance(H, *(np.ascontiguousarray(a, dtype=np.float64) for a in (cs, cd)), T)
        return T
    U, _, Vt = np.linalg.svd(H)
    V = Vt.transpose(0, 2, 1)
    d = np.sign(np.linalg.det(np.matmul(V, U.transpose(0, 2, 1))))
    d[d == 0] = 1.0
    V[:, :, 2] *= d[:, None]  # flip the last axis where needed
    R = np.matmul(V, U.transpose(0, 2, 1))
    T = np.tile(np.eye(4), (len(H), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = cd - np.matmul(R, cs[..., None])[..., 0]
    return T


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray]:
    """Similarity ``dst ~ s R src + t`` (Umeyama 1991): returns ``(s, T)`` with T holding R and t; det R = +1."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    cs, cd = src.mean(0), dst.mean(0)
    a, b = src - cs, dst - cd
    H = a.T @ b / len(src)
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    D = np.diag([1.0, 1.0, d])
    R = Vt.T @ D @ U.T
    var = (a ** 2).sum() / len(src)
    s = float((S * np.diag(D)).sum() / var)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = cd - s * R @ cs
    return s, T


def transform(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (N, 3) points."""
    return points @ T[:3, :3].T + T[:3, 3]
