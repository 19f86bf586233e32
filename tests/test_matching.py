"""Descriptor matching options: k nearest, Lowe's ratio test, mutual nearest neighbours."""
import numpy as np

from pcdet.config import MatchingConfig
from pcdet.matching import Candidates, match_bounded, match_features


def test_k_nearest_includes_the_true_match(rng):
    model = rng.random((200, 33)).astype(np.float32)
    scene = model[:50] + rng.normal(0, 0.01, (50, 33)).astype(np.float32)
    c = match_features(scene, model, MatchingConfig(k=3))
    assert c.model.shape == (50, 3)
    assert (c.model[:, 0] == np.arange(50)).all()
    assert (np.diff(c.distance, axis=1) >= 0).all()  # sorted nearest first


def test_ratio_test_drops_ambiguous(rng):
    model = rng.random((100, 33)).astype(np.float32)
    model[1] = model[0] + 1e-4  # two near-identical model descriptors: matches to them are ambiguous
    scene = model[[0, 5, 6]].copy()
    scene[0] += 0.05  # about equally far from model rows 0 and 1
    c = match_features(scene, model, MatchingConfig(ratio=0.8))
    assert c.model.shape == (3, 1)
    assert c.model[0, 0] == -1 and list(c.model[1:, 0]) == [5, 6]


def test_mutual_keeps_only_mutual_pairs(rng):
    model = rng.random((30, 33)).astype(np.float32)
    scene = np.vstack([model[:10], model[:1] + 0.001]).astype(np.float32)  # rows 0 and 10 both near model 0
    c = match_features(scene, model, MatchingConfig(k=1, mutual=True))
    assert c.model[0, 0] == 0 and c.model[10, 0] == -1  # model 0's nearest scene row is row 0


def test_empty_inputs():
    c = match_features(np.zeros((0, 33), np.float32), np.ones((5, 33), np.float32), MatchingConfig())
    assert len(c) == 0


def test_colour_gate_takes_the_nearest_candidates_of_the_scene_keypoints_colour(rng):
    model = rng.random((40, 33)).astype(np.float32)
    scene = model[:3] + 0.001
    red, grey, unknown = [2.0, 0.5], [1.0, 1.0], [np.nan, np.nan]
    mcol = np.tile(np.array([grey], np.float32), (40, 1))
    mcol[0] = red  # the FPFH-nearest model keypoint of scene row 0 is red; the scene keypoint is grey
    mcol[2] = unknown  # a dark model keypoint: its colour cannot refuse a match
    scol = np.array([grey, grey, grey], np.float32)
    cfg = MatchingConfig(k=2, colour_gate=0.25, colour_pool=40)
    c = match_features(scene, model, cfg, scene_colours=scol, model_colours=mcol)
    assert c.model.shape == (3, 2)
    assert 0 not in c.model[0] and (c.model[0] >= 0).all()  # the red one refused, two grey ones instead
    assert c.model[1, 0] == 1 and c.model[2, 0] == 2
    d = np.linalg.norm(model[c.model[0]] - scene[0], axis=1)
    assert np.all(np.diff(d) >= 0)  # still nearest first in FPFH space
    # without colour at either end, the gate is not applied
    plain = match_features(scene, model, cfg, scene_colours=None, model_colours=mcol)
    assert plain.model[0, 0] == 0


def test_colour_gate_leaves_a_keypoint_of_a_colour_the_model_lacks_without_candidates(rng):
    model = rng.random((30, 33)).astype(np.float32)
    scene = model[:2] + 0.001
    mcol = np.tile(np.array([[1.0, 1.0]], np.float32), (30, 1))
    scol = np.array([[1.0, 1.0], [0.3, 0.4]], np.float32)  # the second is blue-ish: no grey candidate passes
    c = match_features(scene, model, MatchingConfig(k=3, colour_gate=0.25, colour_pool=30), scene_colours=scol,
                       model_colours=mcol)
    assert (c.model[0] >= 0).all() and (c.model[1] == -1).all() and np.isinf(c.distance[1]).all()


def test_library_index_with_one_model_matches_like_the_per_model_search():
    """One model in the index: the same candidates, in the same order, as ``match_features``."""
    from pcdet.matching import LibraryIndex, match_library

    rng = np.random.default_rng(3)
    model, scene = rng.random((600, 33)), rng.random((150, 33))
    (one,) = match_library(scene, LibraryIndex.build([model], [None]), MatchingConfig(k=8))
    ref = match_features(scene, model, MatchingConfig(k=8))
    np.testing.assert_array_equal(one.model, ref.model)
    np.testing.assert_allclose(one.distance, ref.distance)


def test_library_index_gives_candidates_to_the_models_the_scene_resembles():
    """Scene descriptors copied (plus tiny noise) from model A's: with a pool of 16 over A and two unrelated
    models, every scene keypoint's first candidate is its source row of A, A gets the full k = 4, and the
    unrelated models (their descriptors far away in FPFH space) get no candidate at all."""
    from pcdet.matching import LibraryIndex, match_library

    rng = np.random.default_rng(4)
    a = rng.random((400, 33))
    others = [rng.random((400, 33)) + 5.0, rng.random((400, 33)) - 5.0]
    src = rng.choice(400, 100, replace=False)
    scene = a[src] + rng.normal(0, 1e-4, (100, 33))
    ca, cb, cc = match_library(scene, LibraryIndex.build([a, *others], [None, None, None]),
                               MatchingConfig(k=4, library_pool=16))
    assert (ca.model[:, 0] == src).all() and (ca.model >= 0).all()
    assert (cb.model < 0).all() and (cc.model < 0).all()


def test_library_search_on_principal_components():
    """``LibraryIndex.nearest`` with ``dims``: on all 33 components it returns the exact k nearest (the
    projection is a rotation, so the 8 k nearest there hold them); on the first 12 of descriptors whose variance
    lies in 10 directions (plus 1 % noise) it keeps at least 95 % of the exact 16 nearest and the exact nearest
    for at least 98 % of the queries. Distances are the full ones, nearest first."""
    from pcdet.matching import LibraryIndex

    rng = np.random.default_rng(5)
    mix = rng.normal(size=(10, 33))
    feats = [rng.normal(size=(1500, 10)) @ mix + rng.normal(0, 0.01, (1500, 33)) for _ in range(3)]
    index = LibraryIndex.build(feats, [None, None, None])
    q = rng.normal(size=(200, 10)) @ mix + rng.normal(0, 0.01, (200, 33))
    d0, i0 = index.nearest(q, 16)
    d33, i33 = index.nearest(q, 16, dims=33)
    np.testing.assert_array_equal(i33, i0)
    np.testing.assert_allclose(d33, d0, rtol=1e-9)
    d12, i12 = index.nearest(q, 16, dims=12)
    assert np.mean([len(set(a) & set(b)) / 16 for a, b in zip(i12, i0)]) >= 0.95
    assert np.mean(i12[:, 0] == i0[:, 0]) >= 0.98
    assert (np.diff(d12, axis=1) >= 0).all()
    np.testing.assert_allclose(d12, np.linalg.norm(index.tree.data[i12] - q[:, None], axis=2), rtol=1e-9)


def test_approximate_search_stays_within_its_bound(rng):
    """With ``eps`` the r-th candidate is at most (1 + eps) times as far as the true r-th nearest; eps = 0 is the
    exact search (brute force here). On uniform 33-D data a KD-tree prunes little, so eps = 2 is used to show that
    the setting reaches the search: many lists then differ from the exact ones, all within the bound."""
    model = rng.random((3000, 33))
    scene = rng.random((300, 33))
    exact = np.sort(np.linalg.norm(scene[:, None] - model[None], axis=2), axis=1)[:, :8]
    c0 = match_features(scene, model, MatchingConfig(k=8, eps=0.0, colour_gate=0.0))
    np.testing.assert_allclose(c0.distance, exact, rtol=1e-9)
    c = match_features(scene, model, MatchingConfig(k=8, eps=2.0, colour_gate=0.0), workers=2)
    assert (np.abs(c.distance - exact) > 1e-12).any(axis=1).mean() > 0.2  # measured: 0.58 of the lists
    assert (c.distance <= 3.0 * exact + 1e-12).all()
    c1 = match_features(scene, model, MatchingConfig(k=8, eps=2.0, colour_gate=0.0), workers=1)
    np.testing.assert_array_equal(c.model, c1.model)  # each query on its own: the same on any thread count


def test_nearest_rows_keeps_the_keypoints_whose_candidates_are_nearest():
    """The n rows with the smallest mean candidate distance (missing candidates left out of the mean); a row
    without any candidate is never kept, ties go to the earlier row."""
    model = np.array([[0, 1], [2, -1], [-1, -1], [3, 4], [5, 6]])
    distance = np.array([[1.0, 3.0], [1.5, np.inf], [np.inf, np.inf], [0.5, 0.6], [2.0, 2.0]])
    c = Candidates(model, distance)
    assert list(np.flatnonzero(c.nearest_rows(2))) == [1, 3]  # means 2.0, 1.5, -, 0.55, 2.0
    assert list(np.flatnonzero(c.nearest_rows(3))) == [0, 1, 3]  # row 0 before row 4 at the same mean
    assert list(np.flatnonzero(c.nearest_rows(10))) == [0, 1, 3, 4]


def test_nearest_rows_divided_by_the_spread_prefer_keypoints_unlike_the_scene():
    """With ``spread`` (each row's distance to the rest of the scene in FPFH space) the rows are ranked by mean
    candidate distance / spread: a row a little farther from the model but far from every other scene keypoint
    comes before one near the model that looks like much of the scene."""
    model = np.array([[0, 1], [2, 3], [4, 5]])
    distance = np.array([[1.0, 1.0], [1.2, 1.2], [2.0, 2.0]])
    c = Candidates(model, distance)
    assert list(np.flatnonzero(c.nearest_rows(1))) == [0]
    spread = np.array([0.5, 3.0, 1.0])  # ratios 2.0, 0.4, 2.0
    assert list(np.flatnonzero(c.nearest_rows(1, spread))) == [1]
    assert list(np.flatnonzero(c.nearest_rows(2, spread))) == [0, 1]  # row 0 before row 2 at the same ratio


def test_scene_spread_is_the_kth_nearest_among_a_sample_of_the_scene(rng):
    """``Scene.spread(k, eps)``: each keypoint's distance to its (k // (k // 8))-th nearest other keypoint among
    every (k // 8)-th one (FPFH space); exact at eps 0 (checked against brute force, 1e-6 relative: float32
    descriptors), within (1 + eps) of it otherwise, and the same on any number of threads. A descriptor far from
    the others has the largest spread."""
    from scipy.spatial.distance import cdist

    from pcdet.scene import Scene

    desc = rng.random((600, 33)).astype(np.float32)
    desc[7] += 5.0  # unlike the rest

    def scene(workers=1):
        return Scene(np.zeros((600, 3)), np.zeros((600, 3)), np.zeros(600, np.int64), None, np.arange(600), desc,
                     lrf_radius=0.02, workers=workers)

    sample = np.arange(0, 600, 4)  # k 32: every 4th keypoint, the 8th nearest of those
    d = cdist(desc.astype(np.float64), desc[sample].astype(np.float64))
    d[sample, np.arange(len(sample))] = np.inf  # a sampled keypoint is not its own neighbour
    truth = np.sort(d, axis=1)[:, 7]
    exact = scene().spread(32, 0.0)
    np.testing.assert_allclose(exact, truth, rtol=1e-6)
    approx = scene().spread(32, 2.0)
    assert (approx >= exact * (1 - 1e-6)).all() and (approx <= 3.0 * exact * (1 + 1e-6)).all()
    np.testing.assert_array_equal(scene(workers=3).spread(32, 2.0), approx)
    assert int(np.argmax(exact)) == 7
    few = Scene(np.zeros((20, 3)), np.zeros((20, 3)), np.zeros(20, np.int64), None, np.arange(20), desc[:20],
                lrf_radius=0.02)
    np.testing.assert_array_equal(few.spread(32, 2.0), np.ones(20))  # 5 sampled keypoints: none is preferred


def test_bounded_matching_chooses_on_the_coarse_search_and_matches_the_chosen_again(rng):
    """``match_bounded`` keeps at most ``keep`` rows. With ``screen_eps`` they are the ``keep`` nearest on the
    coarser search, and each chosen row's candidates are exactly those the ``eps`` search gives it alone; the
    others keep the coarse ones. With ``screen_eps = 0`` the choice is ``nearest_rows`` of the ``eps`` search.
    Uniform 33-D data, where eps = 2 changes many lists (see above)."""
    model, scene = rng.random((3000, 33)), rng.random((400, 33))
    fine = MatchingConfig(k=8, eps=0.0, colour_gate=0.0, screen_eps=0.0)
    full = match_features(scene, model, fine)
    found, chosen = match_bounded(scene, model, fine, 100)
    np.testing.assert_array_equal(chosen, full.nearest_rows(100))
    np.testing.assert_array_equal(found.model, full.model)

    cfg = MatchingConfig(k=8, eps=0.0, colour_gate=0.0, screen_eps=2.0)
    coarse = match_features(scene, model, MatchingConfig(k=8, eps=2.0, colour_gate=0.0))
    found, chosen = match_bounded(scene, model, cfg, 100, workers=2)
    np.testing.assert_array_equal(chosen, coarse.nearest_rows(100))
    assert chosen.sum() == 100
    np.testing.assert_array_equal(found.model[chosen], full.model[chosen])
    np.testing.assert_array_equal(found.model[~chosen], coarse.model[~chosen])
    assert not np.array_equal(coarse.nearest_rows(100), full.nearest_rows(100))  # the screen reached the choice
    everything, all_rows = match_bounded(scene, model, cfg, 0)  # no bound: every row, the eps search
    assert all_rows.all() and np.array_equal(everything.model, full.model)
