"""6-DoF Hough voting for correspondence grouping, after Tombari and Di Stefano (PSIVT 2010).

Each model keypoint stores the offset to the model's reference point in its own local reference frame. A
correspondence (scene keypoint s with frame F_s, model keypoint m with frame F_m) votes for where the
reference point lies in the scene: s + F_s^T F_m (c - m), and for the rotation F_s^T F_m. A frame's z axis is
the keypoint's oriented normal (toward the camera in the scene, outward on the model) and its x axis the SHOT
frame's x made perpendicular to it: on real frames SHOT's own z sign flips on 19-47 % of the correct matches
(6 LINEMOD cat frames), where most normals agree within 20 degrees.

The x axis repeats far worse: on the correct matches of every 4th real cat frame, the two frames (z from the
normals) differ by a median of 64 degrees, most of it about the normal, which throws most correct votes out of
the peak. With ``spin`` (the default) a correspondence
therefore votes along the whole circle its reference point can lie on when only the normals are trusted: the
offset turned about the normal, with votes about one bin apart. The first is the x axis's own vote, and it
weighs ``1 + x_weight``: where the x axes do repeat (clean scans), those votes still make the peak. Each peak's
voters then take the turn that brings their reference point nearest the peak, so a correct match's rotation is
off by its normal's error only.

Votes go into a 3D grid with trilinear interpolation; every local maximum with at least ``min_votes`` is a
candidate. Its voters (correspondences whose predicted reference point falls within 1.5 bins of the peak) are
then required to agree on the rotation too, which makes the grouping 6-DoF: the voter whose rotation has the
most others within ``rotation_tol_deg`` (among at most 64 evenly spaced voters) anchors a group, fitted by
Kabsch. Up to ``rotations_per_peak`` groups are taken from one peak, each from the voters that disagree with the
earlier ones by more than twice the tolerance: a part that looks alike turned over puts a wrong rotation and the
true one on the same spot. The ``4 * max_groups`` candidates with the most matches within ``inlier_distance``
are refit robustly, and those that describe the same instance are merged (most inliers first). Deterministic:
no random draws.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from ..align import kabsch
from ..errors import ConfigError
from ..matching import Candidates
from ..params import check_positive, param
from ..residuals import within
from .common import correspondence_points, distinct_poses, ramp, refit_batch
from .hypothesis import Hypothesis

if TYPE_CHECKING:
    from ..prepared_model import PreparedModel
    from ..scene import SceneKeypoints
    from . import GroupingConfig

try:  # the compiled kernel, where the install could build it
    from .. import _votes
except ImportError:  # pragma: no cover - exercised where no compiler was at hand
    _votes = None

DENSE_CELLS = 4_000_000  # the vote grid is dense up to this many cells (32 MB), sparse beyond


def compiled() -> bool:
    """Whether the votes are summed, and each peak's voters found, by the compiled kernel (otherwise numpy and scipy
    give the same)."""
    return _votes is not None


@dataclass(frozen=True)
class HoughConfig:
    """Options of 6-DoF Hough voting."""

    bin: float = param(0.015, "m; Hough accumulator cell size")
    min_votes: float = param(4.0, "votes a Hough peak needs (trilinear weights)")
    rotation_tol_deg: float = param(20.0, "degrees; a peak's voters must agree on the rotation within this")
    max_groups: int = param(12, "hypotheses kept per model, most inliers first")
    spin: bool = param(True, "vote along the circle of turns about each normal (the LRF's x axis is not trusted)")
    rotations_per_peak: int = param(3, "rotation groups taken from one vote peak, largest first")
    x_weight: float = param(3.0, "with spin: extra weight of the vote the LRF's own x axis casts")

    def __post_init__(self):
        check_positive(self, "bin", "min_votes", "rotation_tol_deg", "max_groups", "rotations_per_peak")
        if self.x_weight < 0:
            raise ConfigError(f"HoughConfig.x_weight must be >= 0, got {self.x_weight}")


class HoughGrouper:
    """Hypotheses from Hough votes; needs the scene keypoints' and the model keypoints' LRFs."""

    name = "hough"
    Config = HoughConfig
    needs_lrfs = True

    def __init__(self, cfg: "GroupingConfig"):
        self.common, self.cfg = cfg, cfg.hough

    def group(self, scene: "SceneKeypoints", model: "PreparedModel", candidates: Candidates,
              rng: np.random.Generator, *, workers: int = 1) -> list[Hypothesis]:
        """Hypotheses from the vote peaks of ``candidates`` (see the module docstring); needs ``scene.lrfs``."""
        m, c, min_inl = model.model, self.cfg, self.common.min_inliers
        cand = candidates.model
        scene_lrf, model_pts, model_lrf = scene.lrfs, m.kp_points, m.kp_lrfs
        S, k = cand.shape
        flat = cand.reshape(-1)
        corr = np.flatnonzero(flat >= 0)
        si, mi = corr // k, flat[corr]
        if not c.spin:  # the x axis decides the vote: it must exist
            ok = ~np.isnan(scene_lrf[si, 0, 0]) & ~np.isnan(model_lrf[mi, 0, 0])
            corr, si, mi = corr[ok], si[ok], mi[ok]
        if len(corr) < min_inl:
            return []
        # z from the oriented normals, x from SHOT (see the module docstring)
        Fs, Fm = _about_normal(scene_lrf[si], scene.normals[si]), _about_normal(model_lrf[mi], m.kp_normals[mi])
        if c.spin:  # x only places the first vote on the circle: any x where SHOT gives none
            Fs, Fm = _fill_x(Fs, scene.normals[si]), _fill_x(Fm, m.kp_normals[mi])
        ok = ~np.isnan(Fs[:, 0, 0]) & ~np.isnan(Fm[:, 0, 0])
        corr, si, mi, Fs, Fm = corr[ok], si[ok], mi[ok], Fs[ok], Fm[ok]
        if len(corr) < min_inl:
            return []
        local = np.einsum("nij,nj->ni", Fm, model.reference - model_pts[mi])  # offset in the model keypoint's frame
        if c.spin:
            owner, theta = _spin(local, c.bin)  # vote -> correspondence, and the vote's turn of the scene frame
            centre = _spun_centres(scene.points[si], Fs, local, owner, theta)
            # the vote at the LRF's own x (each correspondence's first) counts more: where x repeats, it makes the peak
            weight = 1.0 + c.x_weight * np.r_[True, owner[1:] != owner[:-1]]
        else:
            owner, weight = np.arange(len(corr)), None
            centre = scene.points[si] + np.einsum("nji,nj->ni", Fs, local)  # back to the scene: F^T local
        dense = _dense_box(centre, c.bin)  # the grid's box, once for the sums and the voters
        peaks = _vote_peaks(centre, c.bin, c.min_votes, weight, dense=dense)
        if not peaks:
            return []
        used = peaks[: 4 * c.max_groups]
        cos_tol, cos_apart = np.cos(np.radians(c.rotation_tol_deg)), np.cos(np.radians(2 * c.rotation_tol_deg))
        cands, group_sizes = [], []
        # voters: predicted reference points within 1.5 bins of a peak (grid index c sits at (c + 0.5) * bin)
        near = _peak_votes(centre, c.bin, np.array([cell for cell, _ in used]), dense=dense)
        for (cell, _), votes in zip(used, near):
            peak = (cell + 0.5) * c.bin
            voters = np.unique(owner[votes])  # correspondences
            if len(voters) < min_inl:
                continue
            # each voter's rotation, model frame -> scene frame: F_s^T F_m, with F_s turned to the peak under spin
            Fp = _turn_towards(Fs[voters], local[voters], scene.points[si[voters]], peak) if c.spin else Fs[voters]
            Rv = np.einsum("nji,njk->nik", Fp, Fm[voters])
            # anchor candidates: all voters, or an evenly spaced 64 of them when there are more (deterministic)
            anchors = np.unique(np.linspace(0, len(voters) - 1, min(len(voters), 64)).astype(np.int64))
            cosang = (np.einsum("aij,bij->ab", Rv[anchors], Rv) - 1) / 2  # cos of the relative rotations
            agree, free = cosang > cos_tol, np.ones(len(voters), bool)
            for _ in range(c.rotations_per_peak):
                a = int(np.argmax((agree & free).sum(axis=1)))
                group = voters[agree[a] & free]
                if len(np.unique(si[group])) < min_inl:
                    break
                cands.append(kabsch(model_pts[mi[group]], scene.points[si[group]]))
                group_sizes.append(len(group))
                free &= cosang[a] <= cos_apart  # the next group turns well away from this one
        if not cands:
            return []
        cs, cm = correspondence_points(scene.points, cand, model_pts)
        valid = np.flatnonzero(flat >= 0)
        cands, tau = np.array(cands), self.common.inlier_distance
        if len(cands) > 4 * c.max_groups:  # the robust refit is for the poses that already explain most matches
            count = np.array([len(i) for i in within(cands, cm[valid], cs[valid], tau)])
            best = np.sort(np.lexsort((np.arange(len(count)), -count))[: 4 * c.max_groups])
            cands, group_sizes = cands[best], [group_sizes[i] for i in best]
        T, inls = refit_batch(cands, cm[valid], cs[valid], tau)
        size = np.array([len(np.unique(valid[i] // k)) for i in inls])
        order = np.lexsort((np.arange(len(size)), -size))
        order = order[size[order] >= min_inl]
        keep = distinct_poses(T, order, m.diameter, c.max_groups)
        return [Hypothesis(model.index, T[i], valid[inls[i]], group_sizes[i]) for i in keep]


def _about_normal(F: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(n, 3, 3) frames (rows x, y, z) with z the unit ``normals`` (n, 3) and x the frames' ``F`` x axis made
    perpendicular to it; NaN where that x lies within 10 degrees of the normal."""
    z = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    x = F[:, 0] - (F[:, 0] * z).sum(axis=1, keepdims=True) * z
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    out = np.stack([x / np.maximum(norm, 1e-12), np.cross(z, x / np.maximum(norm, 1e-12)), z], axis=1)
    out[norm[:, 0] < np.sin(np.radians(10))] = np.nan
    return out


def _fill_x(F: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``F`` (n, 3, 3) with its NaN frames replaced by the frame about the unit normal whose x is the world axis
    least aligned with it (projected)."""
    bad = np.isnan(F[:, 0, 0])
    if not bad.any():
        return F
    z = normals[bad] / np.linalg.norm(normals[bad], axis=1, keepdims=True)
    e = np.eye(3)[np.argmin(np.abs(z), axis=1)]
    x = e - (e * z).sum(axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    F = F.copy()
    F[bad] = np.stack([x, np.cross(z, x), z], axis=1)
    return F


def _turn_towards(F: np.ndarray, local: np.ndarray, s: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The frames ``F`` (n, 3, 3) turned about their z so that ``s + F'^T local`` (s, local: (n, 3)) comes
    nearest to ``target`` (3,)."""
    q = np.einsum("nij,nj->ni", F, target - s)
    theta = np.arctan2(q[:, 1], q[:, 0]) - np.arctan2(local[:, 1], local[:, 0])
    return np.einsum("nij,njk->nik", _turns(theta), F)


def _spin(local: np.ndarray, b: float) -> tuple[np.ndarray, np.ndarray]:
    """Votes around the circle: for each offset ``local`` (n, 3, in its keypoint's frame), angles about the
    frame's z evenly spaced so that neighbouring votes lie about ``b`` m apart (at least one, at most 64; the
    first at angle 0). Returns ``(owner (V,), theta (V,))``: the offset each vote belongs to and the turn of
    the scene frame about its z (radians; the turned frame is ``_turns(theta) @ F_s``)."""
    r = np.hypot(local[:, 0], local[:, 1])
    n = np.clip(np.ceil(2 * np.pi * r / b), 1, 64).astype(np.int64)
    owner = np.repeat(np.arange(len(local)), n)
    return owner, 2 * np.pi * ramp(n) / n[owner]


def _spun_centres(s: np.ndarray, F: np.ndarray, local: np.ndarray, owner: np.ndarray, theta: np.ndarray
                  ) -> np.ndarray:
    """(V, 3) reference points voted for: ``s + F'^T local`` of the correspondence ``owner`` (V,) with its frame
    turned about z by ``theta`` (V,), for scene points s (n, 3), frames F (n, 3, 3) and offsets local (n, 3).
    With F' = Rz F this is ``s + cos(theta) a + sin(theta) b + z l_z``, where a = x l_x + y l_y and
    b = y l_x - x l_y: three (n, 3) terms per correspondence instead of a (3, 3) product per vote."""
    x, y, z = F[:, 0], F[:, 1], F[:, 2]
    lx, ly, lz = local[:, :1], local[:, 1:2], local[:, 2:]
    a, b, c = x * lx + y * ly, y * lx - x * ly, s + z * lz
    return c[owner] + np.cos(theta)[:, None] * a[owner] + np.sin(theta)[:, None] * b[owner]


def _turns(theta: np.ndarray) -> np.ndarray:
    """(n, 3, 3) turns of a frame about its own z by ``theta`` (n,) radians: row x of ``Rz @ F`` is
    cos(theta) x + sin(theta) y."""
    c, s = np.cos(theta), np.sin(theta)
    Rz = np.zeros((len(theta), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, s, -s, c, 1.0
    return Rz


def _dense_box(centre: np.ndarray, b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The votes ``centre`` (V, 3) as the compiled kernel reads them (contiguous float64) and their grid's box of
    cell ``b`` m (lowest cell index (3,) and cells per axis (3,), a margin of one cell round the votes), where the
    kernel is built and the box has at most ``DENSE_CELLS`` cells; None otherwise (numpy and scipy then answer)."""
    if _votes is None or len(centre) == 0:
        return None
    c = np.ascontiguousarray(centre, dtype=np.float64)
    box = _votes.box(c, float(b))
    lo, span = np.array(box[:3], np.int64), np.array(box[3:], np.int64)
    return (c, lo, span) if int(np.prod(span)) <= DENSE_CELLS else None


def _peak_votes(centre: np.ndarray, b: float, cells: np.ndarray, *, dense) -> list[np.ndarray]:
    """For each peak of ``cells`` (P, 3) (grid indices as ``_vote_peaks`` gives them; the peak at (cell + 0.5) b),
    the ascending indices of the votes ``centre`` (V, 3) within 1.5 ``b`` of it. With a ``dense`` box
    (``_dense_box`` of the same votes) the compiled kernel buckets the votes by cell and looks at the cells
    around each peak; otherwise (None) a KD-tree of the votes in those cells (``_near_cells``) answers. Both keep a
    vote at exactly 1.5 b."""
    r = 1.5 * b
    peaks = (cells + 0.5) * b
    if dense is not None and len(cells):
        c, lo, span = dense
        out = np.frombuffer(_votes.near(c, float(b), lo, span, np.ascontiguousarray(cells, dtype=np.int64),
                                        np.ascontiguousarray(peaks, dtype=np.float64), float(r)), np.int64)
        P = len(cells)
        return np.split(out[P:], np.cumsum(out[:P])[:-1])
    near = _near_cells(centre, b, cells)  # votes that can be within 1.5 bins
    tree = cKDTree(centre[near])
    return [np.sort(near[np.array(tree.query_ball_point(p, r), dtype=np.int64)]) for p in peaks]


def _near_cells(centre: np.ndarray, b: float, cells: np.ndarray) -> np.ndarray:
    """Indices of the votes ``centre`` (V, 3) whose grid cell (as ``_vote_peaks`` indexes them) is one that a
    point within 1.5 ``b`` of some peak (``cells`` (P, 3), at (cell + 0.5) * b) can fall in: the cells from
    peak - 2 to peak + 1 on each axis. Only these can be a peak's voters."""
    base = np.floor(centre / b - 0.5).astype(np.int64)
    offsets = np.array([(i, j, m) for i in range(-2, 2) for j in range(-2, 2) for m in range(-2, 2)])
    block = (cells.astype(np.int64)[:, None, :] + offsets[None]).reshape(-1, 3)
    lo = np.minimum(base.min(axis=0), block.min(axis=0))
    span = np.maximum(base.max(axis=0), block.max(axis=0)) - lo + 1

    def code(x):
        return ((x[:, 0] - lo[0]) * span[1] + x[:, 1] - lo[1]) * span[2] + x[:, 2] - lo[2]

    return np.flatnonzero(np.isin(code(base), code(block)))


def _vote_peaks(centre: np.ndarray, b: float, min_votes: float, weight: np.ndarray | None = None, *,
                dense) -> list[tuple[np.ndarray, float]]:
    """Trilinear votes of the points ``centre`` (N, 3), each of ``weight`` (N,; default 1), into a grid of cell
    ``b`` m; the cells that are maxima of
    their 26-neighbourhood with at least ``min_votes``, strongest first (ties by cell index), as (cell index (3,),
    votes). The grid is dense over the votes' bounding box when that has at most ``DENSE_CELLS`` cells, else
    sparse; both give the same peaks. With a ``dense`` box (``_dense_box`` of the same votes) the compiled
    kernel (``pcdet/_votes.c``) sums the grid in numpy's order, so to the bit as numpy's bincount; None: numpy."""
    if len(centre) == 0:
        return []
    if dense is not None:
        c, lo, span = dense
        votes = np.zeros(int(np.prod(span)))
        _votes.accumulate(c, float(b), np.zeros(0) if weight is None else np.ascontiguousarray(weight, np.float64),
                          lo, span, votes)
        return _dense_peaks(votes, span, lo, min_votes)
    g = centre / b - 0.5
    base = np.floor(g).astype(np.int64)
    frac = g - base
    lo = base.min(axis=0) - 1  # a margin of one empty cell on every side
    span = base.max(axis=0) - lo + 3
    rel = base - lo
    code = (rel[:, 0] * span[1] + rel[:, 1]) * span[2] + rel[:, 2]
    codes, weights = [], []
    side = [(1 - frac[:, i], frac[:, i]) for i in range(3)]  # each axis's weight toward the lower, upper cell
    for dx in (0, 1):
        for dy in (0, 1):
            wxy = side[0][dx] * side[1][dy]
            for dz in (0, 1):
                codes.append(code + (dx * span[1] + dy) * span[2] + dz)
                w = wxy * side[2][dz]
                weights.append(w if weight is None else w * weight)
    codes, weights = np.concatenate(codes), np.concatenate(weights)
    if int(np.prod(span)) <= DENSE_CELLS:
        return _dense_peaks(np.bincount(codes, weights=weights, minlength=int(np.prod(span))), span, lo, min_votes)
    ucode, inv = np.unique(codes, return_inverse=True)
    votes = np.bincount(inv.reshape(-1), weights=weights)
    keep = votes >= min_votes
    cand, v = ucode[keep], votes[keep]
    nb = cand[:, None] + _steps(span)[None, :]
    pos = np.minimum(np.searchsorted(ucode, nb), len(ucode) - 1)
    nbv = np.where(ucode[pos] == nb, votes[pos], 0.0)
    return _strongest(cand, v, np.all(nbv <= v[:, None], axis=1), span, lo)


def _steps(span: np.ndarray) -> np.ndarray:
    """(26,) how a cell's code differs from its neighbours' on a grid of ``span`` cells (the margin of
    ``_vote_peaks`` keeps every voted cell's neighbours in the box)."""
    return np.array([(i * span[1] + j) * span[2] + m for i in (-1, 0, 1) for j in (-1, 0, 1) for m in (-1, 0, 1)
                     if (i, j, m) != (0, 0, 0)])


def _dense_peaks(votes: np.ndarray, span: np.ndarray, lo: np.ndarray, min_votes: float
                 ) -> list[tuple[np.ndarray, float]]:
    """``_vote_peaks``'s answer from the dense grid of summed ``votes`` (span0 * span1 * span2,)."""
    cand = np.flatnonzero(votes >= min_votes)
    v = votes[cand]
    is_peak = np.all(votes[cand[:, None] + _steps(span)[None, :]] <= v[:, None], axis=1)
    return _strongest(cand, v, is_peak, span, lo)


def _strongest(cand: np.ndarray, v: np.ndarray, is_peak: np.ndarray, span: np.ndarray, lo: np.ndarray
               ) -> list[tuple[np.ndarray, float]]:
    """``_vote_peaks``'s answer from the candidate cells' codes ``cand`` (P,), their votes ``v`` (P,) and whether each
    is a peak: the peaks, strongest first (ties by cell index), as (cell index (3,), votes)."""
    cand, v = cand[is_peak], v[is_peak]
    order = np.lexsort((cand, -v))  # strongest first; the code orders cells as their index tuples do
    cells = np.column_stack([cand // (span[1] * span[2]), cand // span[2] % span[1], cand % span[2]]) + lo
    return [(cells[o].astype(float), float(v[o])) for o in order]
