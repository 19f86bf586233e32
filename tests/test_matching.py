"""Descriptor matching options: k nearest, Lowe's ratio test, mutual nearest neighbours."""
import numpy as np

from pcdet.config import MatchingConfig
from pcdet.matching import match_features


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
