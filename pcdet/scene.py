"""What one frame becomes before matching: the scene cloud, its keypoints and descriptors, and the views of the
keypoints that the groupers work on. Built once per frame; everything derived from it is computed on first
use and kept (thread-safe, and the same whatever the order of the requests).
"""
from __future__ import annotations

import threading
from typing import Callable, Hashable, TypeVar

import numpy as np
from scipy.spatial import cKDTree

from .cloud import Plane, voxel_downsample
from .grid import GridTree
from .lrf import shot_lrf

V = TypeVar("V")

SPREAD_NEIGHBOURS = 8  # Scene.spread searches every (k // this)-th keypoint


class _Memo:
    """Values computed on first request and kept; one lock per key, so that two threads asking for the same
    value compute it once and different values in parallel."""

    def __init__(self):
        self._values: dict = {}
        self._locks: dict = {}
        self._lock = threading.Lock()

    def get(self, key: Hashable, compute: Callable[[], V]) -> V:
        if key in self._values:
            return self._values[key]
        with self._lock:
            lock = self._locks.setdefault(key, threading.Lock())
        with lock:
            if key not in self._values:
                self._values[key] = compute()
        return self._values[key]


class SceneKeypoints:
    """The scene keypoints one grouper call works on (camera frame, metres).

    points, normals : (S, 3); labels : (S,) int64 Euclidean cluster of each (all 0 when unknown);
    lrfs : (S, 3, 3) SHOT frames (rows x, y, z; NaN where invalid), given as an array or as a function of
        ``index`` that computes them on first use (``Scene.lrfs_of``); None when there are none;
    cloud_tree : KD-tree of the whole scene cloud the keypoints come from, or None;
    index : (S,) positions of these keypoints in the frame's keypoint list.
    ``cached(key, compute)`` keeps what a grouper derives from the view (its point pairs, say) for the next
    model that uses the same view.
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, *, labels: np.ndarray | None = None,
                 lrfs: np.ndarray | Callable[[np.ndarray], np.ndarray] | None = None, cloud_tree: cKDTree | None = None,
                 index: np.ndarray | None = None):
        self.points = np.asarray(points, float)
        self.normals = np.asarray(normals, float)
        self.labels = np.zeros(len(self.points), np.int64) if labels is None else np.asarray(labels)
        self._lrfs = lrfs
        self.cloud_tree = cloud_tree
        self.index = np.arange(len(self.points)) if index is None else index
        self._memo = _Memo()

    @property
    def lrfs(self) -> np.ndarray | None:
        """(S, 3, 3) SHOT frames of the keypoints (NaN where invalid), or None."""
        if callable(self._lrfs):
            return self._memo.get("lrfs", lambda: self._lrfs(self.index))
        return self._lrfs

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, mask: np.ndarray) -> "SceneKeypoints":
        """A new view of the keypoints where ``mask`` (S,) bool is set, with its own cache; its LRFs are computed
        for its own keypoints only, on first use."""
        lrfs = self._lrfs if self._lrfs is None or callable(self._lrfs) else self._lrfs[mask]
        return SceneKeypoints(self.points[mask], self.normals[mask], labels=self.labels[mask], lrfs=lrfs,
                              cloud_tree=self.cloud_tree, index=self.index[mask])

    def cached(self, key: Hashable, compute: Callable[[], V]) -> V:
        """``compute()`` once per ``key`` for this view; later calls (from any thread) get the same value."""
        return self._memo.get(key, compute)


class Scene:
    """One frame's scene, as the stages after preprocessing see it.

    points, normals : (N, 3) voxel-grid scene points (m) and normals facing the camera; labels : (N,) cluster of
    each; plane : the removed supporting plane or None; tree : KD-tree of the points (``grid.GridTree``: its
    short-radius nearest-point queries run on a hashed grid; None when empty);
    keypoints : (K,) int64 indices into points; descriptors : (K, 33) float32 FPFH of each;
    lrf_radius : m, support of the keypoints' local reference frames;
    levels : ``{step: positions in keypoints}`` of the keypoints chosen for each grouping step (m) when they were
        selected at several spacings at once (``keypoints.voxel_keypoint_levels``; the finest is the keypoint
        spacing), or None;
    colours : (K, 2) float32 chromaticity of each keypoint (``colour.chromaticity``; NaN where unknown), or None
        when the frame has no colour image;
    workers : threads of the LRFs' neighbour search (the frames are the same for any number).
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, labels: np.ndarray, plane: Plane | None,
                 keypoints: np.ndarray, descriptors: np.ndarray, *, lrf_radius: float,
                 colours: np.ndarray | None = None, workers: int = 1,
                 levels: dict[float, np.ndarray] | None = None):
        self.points, self.normals, self.labels, self.plane = points, normals, labels, plane
        self.workers = workers
        self.keypoints, self.descriptors, self.colours = keypoints, descriptors, colours
        self.lrf_radius = lrf_radius
        self.levels = levels or {}
        self.tree = GridTree(points) if len(points) else None  # ICP's and the overlap's searches on a grid
        self._memo = _Memo()
        self._lrf_lock = threading.Lock()
        self._lrf = np.full((len(keypoints), 3, 3), np.nan)
        self._lrf_done = np.zeros(len(keypoints), bool)

    @property
    def lrfs(self) -> np.ndarray:
        """(K, 3, 3) SHOT frames of the keypoints (NaN where too few points support one); each computed once."""
        return self.lrfs_of(np.arange(len(self.keypoints)))

    def lrfs_of(self, index: np.ndarray) -> np.ndarray:
        """(len(index), 3, 3) SHOT frames of the keypoints ``index`` (positions in ``keypoints``), computed on
        first request and kept (a frame depends on its keypoint and the cloud only, so the order and the
        grouping of the requests do not change it)."""
        index = np.asarray(index, np.int64)
        with self._lrf_lock:
            todo = np.unique(index[~self._lrf_done[index]])
            if len(todo):
                self._lrf[todo] = shot_lrf(self.points, self.points[self.keypoints[todo]], self.lrf_radius,
                                           self.tree, workers=self.workers)[0]
                self._lrf_done[todo] = True
            return self._lrf[index]

    def spread(self, k: int, eps: float) -> np.ndarray:
        """(K,) each keypoint's FPFH distance to about its ``k``-th nearest other keypoint of the scene: how unlike
        the rest of the scene it looks. Searched among every ``step``-th keypoint (``step = k // SPREAD_NEIGHBOURS``,
        at least 1) for the ``k // step``-th nearest of those, approximately (KD-tree search, each distance within
        ``1 + eps`` of the true one, deterministic). Measured on real frames at ``k`` 32: among every 4th keypoint at
        eps 0.5, a quarter of the time of the search among all (0.016-0.032 s against 0.040-0.123 s on 4,800-8,800
        keypoints), at eps 2 less than half of that again (0.09 against 0.22 s on 31,000), each to a correlation of
        0.99 with the search among all. All ones (no keypoint preferred) when the scene has too few keypoints.
        Computed once per ``(k, eps)``."""
        def compute() -> np.ndarray:
            d = self.descriptors
            step = max(1, k // SPREAD_NEIGHBOURS)
            rank = max(1, k // step)
            sample = d[::step]
            if len(sample) <= rank:
                return np.ones(len(d))
            dist, _ = cKDTree(sample).query(d, k=rank + 1, eps=eps, workers=self.workers)
            # a sampled keypoint finds itself first: its rank-th other neighbour is one column on
            own = np.arange(len(d)) % step == 0
            return np.where(own, dist[:, rank], dist[:, rank - 1])

        return self._memo.get(("spread", k, eps), compute)

    def keypoints_at(self, step: float, *, min_step: float) -> SceneKeypoints:
        """The keypoints at least ``step`` m apart, as a ``SceneKeypoints`` view shared by every model that asks
        for the same step: the level selected at that step (``levels``) when there is one, else the keypoints at
        ``min_step`` (the keypoint spacing) thinned to one per voxel of side ``step`` (all of them when ``step`` is
        within 5 % of ``min_step``). Its LRFs are the frame's, taken on first use."""
        def build() -> SceneKeypoints:
            kp = self.keypoints
            base = self.levels.get(min_step, np.arange(len(kp)))
            if step in self.levels:
                sub = self.levels[step]
            elif step <= min_step * 1.05:
                sub = base
            else:
                sub = base[np.sort(voxel_downsample(self.points[kp[base]], step)[2])]
            return SceneKeypoints(self.points[kp[sub]], self.normals[kp[sub]], labels=self.labels[kp[sub]],
                                  lrfs=self.lrfs_of, cloud_tree=self.tree, index=sub)

        return self._memo.get(("view", step), build)
