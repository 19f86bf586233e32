"""Global hypothesis verification on hand-built scenes whose best subset is known."""
import numpy as np

from pcdet.global_verify import candidate_terms, select


def _grid(x0, x1, y0, y1, z=0.5, step=0.004):
    xs, ys = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)])


def _terms(scene, models, viol=None):
    viol = np.zeros(len(models)) if viol is None else np.asarray(viol, float)
    return candidate_terms(scene, models, viol, 0.006, 0.015)


def test_terms_are_the_brute_force_sets():
    """On a random scene and posed samples: explained = the scene points closer than explain_radius to a sample,
    clutter = those not explained within clutter_radius (or exactly at it) of an explained one, by all distances;
    a candidate whose samples lie beyond every scene point explains nothing and has no clutter."""
    from scipy.spatial.distance import cdist

    rng = np.random.default_rng(3)
    scene = rng.uniform(-0.1, 0.1, (3000, 3))
    models = [scene[rng.choice(3000, 40)] + 0.004 * rng.normal(size=(40, 3)), np.array([[5.0, 5.0, 5.0]])]
    t = _terms(scene, models)
    for P, e, c in zip(models, t.explained, t.clutter):
        want_e = np.flatnonzero(cdist(scene, P).min(axis=1) < 0.006)
        near = (np.flatnonzero(cdist(scene, scene[want_e]).min(axis=1) <= 0.015) if len(want_e)
                else np.zeros(0, np.int64))
        assert np.array_equal(e, want_e) and np.array_equal(c, np.setdiff1d(near, want_e))
    assert len(t.explained[0]) > 20 and len(t.clutter[0]) > len(t.explained[0])
    assert len(t.explained[1]) == len(t.clutter[1]) == 0


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


def _box(x0, x1, y0, y1, z0, z1, step=0.004):
    """Samples of the six faces of an axis-aligned box (m)."""
    xs, ys, zs = (np.arange(a, b + 1e-9, step) for a, b in ((x0, x1), (y0, y1), (z0, z1)))
    faces = []
    for z in (z0, z1):
        X, Y = np.meshgrid(xs, ys)
        faces.append(np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)]))
    for x in (x0, x1):
        Y, Z = np.meshgrid(ys, zs)
        faces.append(np.column_stack([np.full(Y.size, x), Y.ravel(), Z.ravel()]))
    for y in (y0, y1):
        X, Z = np.meshgrid(xs, zs)
        faces.append(np.column_stack([X.ravel(), np.full(X.size, y), Z.ravel()]))
    return np.unique(np.round(np.vstack(faces), 6), axis=0)


def test_what_an_object_stands_on_is_neither_its_clutter_nor_explained_by_it():
    """A 4 cm cube stands on a board 15 mm above the supporting plane (z = 0, normal +z, as preprocessing removes
    it); the board runs on around the cube's base. Seen are the board, the cube's top and two of its sides.
    Without the plane, the board next to the base is the cube's clutter and the true cube is dropped; with the
    plane the board it stands on is left out of its clutter (and of what it explains) and the cube is kept. A slab
    whose top face is fitted into the board (its base 2 cm lower) still has the board around it as clutter, plane
    or not. A 4 mm plate laid into the board (its base 2 mm under the board's surface) explains nothing but board:
    without the plane it is dropped for the board around it, and with the plane that board is neither its clutter
    nor explained by it, so it is dropped still (before, it kept the board as explained and had no clutter)."""
    from pcdet.cloud import Plane

    board = _grid(-0.1, 0.1, -0.1, 0.1, z=0.015)
    board = board[~((board[:, 0] > -0.002) & (board[:, 0] < 0.042) & (board[:, 1] > -0.002) & (board[:, 1] < 0.042))]
    cube = _box(0.0, 0.04, 0.0, 0.04, 0.015, 0.055)
    seen = cube[(cube[:, 2] > 0.0549) | (cube[:, 0] < 1e-6) | (cube[:, 1] < 1e-6)]
    seen = seen[seen[:, 2] > 0.0151]
    scene = np.vstack([board, seen])
    normals = np.tile([0.0, 0.0, 1.0], (len(scene), 1))
    side = np.arange(len(board), len(scene))[seen[:, 2] < 0.0549]
    normals[side] = np.where((seen[seen[:, 2] < 0.0549, 0] < 1e-6)[:, None], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0])
    slab = _box(-0.08, -0.04, -0.08, -0.04, -0.005, 0.015)
    plate = _box(0.05, 0.09, -0.09, -0.05, 0.013, 0.017)
    plane = Plane(np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, np.int64))
    models = [cube, slab, plate]
    bare = candidate_terms(scene, models, np.zeros(3), 0.006, 0.015)
    held = candidate_terms(scene, models, np.zeros(3), 0.006, 0.015, plane=plane, scene_normals=normals)
    assert len(bare.clutter[0]) > 50 and len(held.clutter[0]) == 0
    assert np.array_equal(held.clutter[1], bare.clutter[1]) and len(bare.clutter[1]) > len(bare.explained[1])
    # the cube keeps what it explains of itself; the board ring at its base is no longer its own
    assert np.array_equal(held.explained[0], bare.explained[0][bare.explained[0] >= len(board)])
    assert len(held.explained[0]) == len(seen) and len(bare.explained[0]) > len(seen)
    assert np.array_equal(held.explained[1], bare.explained[1])  # the slab's base is 2 cm under the board
    assert len(bare.explained[2]) > 100 and len(bare.clutter[2]) > 0
    assert len(held.explained[2]) == 0 and len(held.clutter[2]) == 0
    assert select(bare, 1.0, 5.0, 1.0)[0] == []
    assert select(held, 1.0, 5.0, 1.0)[0] == [0]


def test_caps_bound_the_candidates_of_a_group():
    """Two copies of one object side by side, both candidates of group 7: both explain the scene and are chosen;
    capped at one for the group, only the first is."""
    A = _grid(0.0, 0.06, 0.0, 0.06)
    B = _grid(0.1, 0.16, 0.0, 0.06)
    t = _terms(np.vstack([A, B]), [A.copy(), B.copy()])
    assert sorted(select(t, 1.0, 5.0, 1.0)[0]) == [0, 1]
    assert select(t, 1.0, 5.0, 1.0, groups=[7, 7], caps={7: 1})[0] == [0]
    assert sorted(select(t, 1.0, 5.0, 1.0, groups=[7, 7], caps={7: 2})[0]) == [0, 1]
