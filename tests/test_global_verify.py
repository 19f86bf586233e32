"""Global hypothesis verification on hand-built scenes whose best subset is known."""
import numpy as np
from scipy.spatial import cKDTree

from pcdet.global_verify import candidate_terms, select


def _grid(x0, x1, y0, y1, z=0.5, step=0.004):
    xs, ys = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)])


def _terms(scene, models, viol=None):
    viol = np.zeros(len(models)) if viol is None else np.asarray(viol, float)
    return candidate_terms(scene, cKDTree(scene), models, viol, 0.006, 0.015)


def test_a_model_on_part_of_an_unknown_object_is_dropped():
    """Scene: object A (a 6 cm patch) and an unknown 10 cm patch B. Candidate 0 explains A exactly; candidate 1
    explains a 4 cm corner of B and leaves the rest of B unexplained beside it. Only 0 is chosen."""
    A = _grid(0.0, 0.06, 0.0, 0.06)
    B = _grid(0.2, 0.3, 0.0, 0.1)
    scene = np.vstack([A, B])
    t = _terms(scene, [A.copy(), _grid(0.2, 0.24, 0.0, 0.04)])
    assert len(t.clutter[0]) == 0 and len(t.clutter[1]) > 0.5 * len(t.explained[1])
    chosen, f = select(t, 1.0, 5.0, 1.0)
    assert chosen == [0]
    assert f == len(A)  # every point of A explained, nothing else counted


def test_duplicates_and_rival_models_keep_one():
    """Two candidates explaining the same points: the second brings only double claims, so one is kept."""
    A = _grid(0.0, 0.06, 0.0, 0.06)
    t = _terms(A, [A.copy(), A[: len(A) * 3 // 4].copy()])
    chosen, _ = select(t, 1.0, 5.0, 1.0)
    assert chosen == [0]


def test_touching_true_objects_do_not_penalise_each_other():
    """Two library objects 8 mm apart: each is in the other's clutter radius, but both are explained when both
    are chosen, so both are kept."""
    A = _grid(0.0, 0.06, 0.0, 0.06)
    B = _grid(0.068, 0.128, 0.0, 0.06)
    scene = np.vstack([A, B])
    t = _terms(scene, [A.copy(), B.copy()])
    assert len(t.clutter[0]) > 0 and len(t.clutter[1]) > 0
    chosen, f = select(t, 1.0, 5.0, 1.0)
    assert sorted(chosen) == [0, 1]
    assert f == len(scene)


def test_see_through_evidence_counts_against():
    A = _grid(0.0, 0.06, 0.0, 0.06)
    t = _terms(A, [A.copy()], viol=[1.5])  # more violating than supported pixels
    assert select(t, 1.0, 5.0, 1.0)[0] == []
    assert select(t, 1.0, 5.0, 0.5)[0] == [0]


def test_no_candidates():
    scene = _grid(0.0, 0.02, 0.0, 0.02)
    assert select(_terms(scene, []), 1.0, 5.0, 1.0) == ([], 0.0)
