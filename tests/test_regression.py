"""Synthetic regression suites from models/, fixed seeds: 20 scenes with 4 objects each, and 20 crowded scenes.

The scenes are ``pcdet synth``'s defaults: real Kinect edges (``structured_light_band``) and objects rendered from
meshes bent by 1.2 mm RMS, with which twins of real LINEMOD frames match as the real frames do; the crowded suite
also runs on the idealised scenes of before (``structured_light``, the meshes exact).

Thresholds (issue 2): with the ground-truth object ids given (BOP localisation), recall at ADD < 0.1 d of at least
0.85; without them, precision >= 0.9 at recall >= 0.8 (ADD-S < 0.1 d). Measured on this suite: 0.900 with targets
(0.875 before a target kept its spot against a better-scoring pose of another object); 1.000 at 0.938 without
(global verification). On the idealised scenes of the same seed: 0.938 (0.912 before; 0.950 at ADD-S, the same on
the code of 2026-11-30); 1.000 at 0.963 (0.987 at 0.963 with thresholds only). Before the
sensor model had its own random stream the suite's scenes were others (0.875; 0.959 at 0.887), and other seeds
landed on both sides of the bar (seed 7: 0.95; seed 99: 0.825), see docs/measurements.md.
"""
import pytest

from pcdet.config import load_pipeline
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector
from pcdet.evaluate import evaluate
from pcdet.synth import SynthConfig, synthesize


@pytest.fixture(scope="module")
def suite(tmp_path_factory, library):
    out = tmp_path_factory.mktemp("suite")
    return BopDataset(synthesize(library, out, SynthConfig(scenes=20, objects=4, seed=2026)))


def _estimates(ds, det, targets):
    ests = []
    for img in ds:
        r = det.detect(ds.frame(img), ds.targets(img) if targets else None)
        ests += [{"scene_id": img.scene_id, "im_id": img.im_id, "obj_id": d.obj_id, "score": d.score,
                  "T_cam_model": d.T_cam_model} for d in r.detections]
    return ests


@pytest.mark.slow
def test_localisation_recall(suite, library):
    ev = evaluate(suite, _estimates(suite, Detector(library), True), library)
    assert ev.overall["instances"] == 80
    assert ev.overall["recall_add"] >= 0.85, ev.overall


@pytest.mark.slow
def test_detection_precision_and_recall(suite, library):
    ev = evaluate(suite, _estimates(suite, Detector(library), False), library)
    assert ev.overall["recall_adds"] >= 0.8, ev.overall
    assert ev.overall["precision_adds"] >= 0.9, ev.overall


@pytest.fixture(scope="module")
def crowded(tmp_path_factory, library):
    out = tmp_path_factory.mktemp("crowded")
    # the idealised scenes: edge pixels dropped, not seen past, and the meshes exactly as the models
    cfg = SynthConfig(scenes=20, objects=3, instances=3, distractors=3, seed=2026, sensor="structured_light",
                      mesh_error=0)
    return BopDataset(synthesize(library, out, cfg))


@pytest.mark.slow
def test_many_instances_among_distractors(crowded, library):
    """Issue 3: up to 3 copies of each of 3 objects plus 3 clutter shapes not in the library, no targets,
    pipelines/crowded.toml: recall (ADD-S < 0.1 d) >= 0.8 and precision >= 0.9, on the idealised scenes (the
    synth default until 2026-12). Measured: 0.947 / 0.973 on 114 instances (0.956 / 0.973 before the per-model
    keypoint bound and the approximate descriptor search, 0.930 / 0.972 before the ICP budget covered distinct
    spots first, 0.939 / 0.973 before that with single-precision FPFH; on the scenes before the sensor got its
    own random stream, 0.870 / 0.980 on 115, and the default pipeline with per-detection thresholds only 0.791 /
    0.798)."""
    ev = evaluate(crowded, _estimates(crowded, Detector(library, load_pipeline("crowded")), False), library,
                  with_vsd=False)
    assert ev.overall["instances"] == 114
    assert ev.overall["recall_adds"] >= 0.8, ev.overall
    assert ev.overall["precision_adds"] >= 0.9, ev.overall


@pytest.fixture(scope="module")
def crowded_real_edges(tmp_path_factory, library):
    out = tmp_path_factory.mktemp("crowded_real_edges")
    cfg = SynthConfig(scenes=20, objects=3, instances=3, distractors=3, seed=2026)  # synth's defaults
    return BopDataset(synthesize(library, out, cfg))


@pytest.mark.slow
def test_many_instances_with_real_edges_and_mesh_error(crowded_real_edges, library):
    """The crowded suite's scenes (the same poses) as ``pcdet synth`` makes them by default, with what real
    LINEMOD frames showed the idealised scenes lack (``scripts/sim_to_real.py``): object edges seen past instead
    of dropped (``structured_light_band``) and each object rendered from its mesh bent by 1.2 mm RMS
    (``mesh_error``); with both, twins of the real cat frames match as the real frames do. Same floors as the
    idealised suite: recall (ADD-S < 0.1 d) >= 0.8 and precision >= 0.9. Measured: 0.930 / 0.964 (idealised:
    0.947 / 0.973)."""
    ev = evaluate(crowded_real_edges, _estimates(crowded_real_edges, Detector(library, load_pipeline("crowded")),
                                                 False), library, with_vsd=False)
    assert ev.overall["instances"] == 114
    assert ev.overall["recall_adds"] >= 0.8, ev.overall
    assert ev.overall["precision_adds"] >= 0.9, ev.overall


@pytest.fixture(scope="module")
def third_party(tmp_path_factory):
    """scripts/bench_thirdparty.py's suite: 20 scenes, two of five meshes from ../shared/data (LINEMOD's cat,
    the Stanford bunny, YCB-Video's two boxes and mug) with 1-3 copies each, 3 distractors, seed 2026."""
    import importlib.util

    from pcdet.library import ModelLibrary

    from .conftest import ROOT, shared

    for name in ("linemod_cat", "bunny", "ycbv_frame"):
        shared(name)
    spec = importlib.util.spec_from_file_location("bench_thirdparty", ROOT / "scripts" / "bench_thirdparty.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path_factory.mktemp("thirdparty")
    lib = ModelLibrary.from_folder(bench.third_party_models(out / "meshes"), cache_dir=False)
    cfg = SynthConfig(scenes=20, objects=2, instances=3, distractors=3, seed=2026)
    ds = BopDataset(synthesize(lib, out / "suite", cfg))
    return ds, ModelLibrary.from_folder(out / "suite" / "models", cache_dir=False)


@pytest.mark.slow
@pytest.mark.real
def test_many_instances_of_third_party_meshes(third_party):
    """Issue 11: meshes pcdet's authors did not make, up to three copies each among distractors, the default
    pipeline, no targets: recall (ADD-S < 0.1 d) >= 0.9 and precision >= 0.9 on 77 instances, synth's default
    scenes. Measured: 0.935 / 0.960 (2026-12-02); on the idealised scenes of before (``sensor="structured_light"``,
    no mesh error) 0.961 / 0.949 (0.935 / 0.947 before the per-model keypoint bound and the approximate descriptor
    search; 0.883 / 0.944 before the ICP budget covered distinct spots first: the boxes' copies and their
    turned-over poses took every slot); most false detections are boxes on distractor boxes."""
    ds, lib = third_party
    ev = evaluate(ds, _estimates(ds, Detector(lib), False), lib, with_vsd=False)
    assert ev.overall["instances"] == 77
    assert ev.overall["recall_adds"] >= 0.9, ev.overall
    assert ev.overall["precision_adds"] >= 0.9, ev.overall
