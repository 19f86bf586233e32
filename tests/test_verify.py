"""Verification: the true pose explains the depth, a shifted one does not; conflicts resolve greedily."""
import numpy as np

from pcdet.config import VerifyConfig
from pcdet.render import render_meshes
from pcdet.synth import KINECT
from pcdet.verify import resolve_conflicts, verify


def _scene(m, wall=True):
    """The model at 0.6 m in front of a wall at 0.9 m (or of nothing)."""
    import trimesh

    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 0.6]
    meshes = [(m.vertices, m.faces, T)]
    if wall:
        w = trimesh.creation.box((3, 3, 0.01))
        Tw = np.eye(4)
        Tw[2, 3] = 0.9
        meshes.append((w.vertices, w.faces, Tw))
    return T, render_meshes(KINECT, meshes).depth


def test_true_pose_scores_high_and_shift_low(library):
    m = library[2]
    T, depth = _scene(m)
    good = verify(m, T, depth, KINECT, VerifyConfig())
    assert good.score > 0.99 and good.n_violations == 0 and good.accepted(VerifyConfig())
    T2 = T.copy()
    T2[0, 3] += 0.04  # 4 cm sideways: part of it hangs in front of the wall, where the sensor sees the wall
    bad = verify(m, T2, depth, KINECT, VerifyConfig())
    assert bad.score < 0.7 and bad.n_violations > 100
    T3 = T.copy()
    T3[2, 3] += 0.05  # 5 cm behind: the measured surface hides it: occluded, not supported
    hidden = verify(m, T3, depth, KINECT, VerifyConfig())
    assert hidden.n_supported < 0.05 * good.n_supported and not hidden.accepted(VerifyConfig())


def test_pose_over_missing_depth_is_not_free(library):
    m = library[2]
    T, depth = _scene(m, wall=False)
    T2 = T.copy()
    T2[0, 3] += 0.06  # mostly over pixels with no measurement at all
    good, bad = verify(m, T, depth, KINECT, VerifyConfig()), verify(m, T2, depth, KINECT, VerifyConfig())
    assert bad.score < good.score - 0.2


def test_conflicts():
    sup = [np.arange(0, 100), np.arange(50, 150), np.arange(200, 260)]
    assert resolve_conflicts([0, 1, 2], sup, 0.3, 300) == [0, 2]  # 1 overlaps 0 by 50 %
    assert resolve_conflicts([1, 0, 2], sup, 0.6, 300) == [1, 0, 2]
