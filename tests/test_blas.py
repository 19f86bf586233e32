"""pcdet.blas: BLAS limited to one thread while pcdet works, and restored afterwards."""
from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from pcdet.blas import one_blas_thread


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_one_blas_thread_limits_within_and_restores_after():
    """Starting from 3 threads in every loaded BLAS: 1 inside the block (nested blocks too), 3 again after it,
    also when the block raises."""
    assert _blas_threads(), "numpy's BLAS is not visible to threadpoolctl"
    with threadpool_limits(3, user_api="blas"):
        with one_blas_thread():
            assert set(_blas_threads()) == {1}
            with one_blas_thread():
                assert set(_blas_threads()) == {1}
            assert set(_blas_threads()) == {1}  # the inner block leaves the outer one's limit in place
        assert set(_blas_threads()) == {3}
        try:
            with one_blas_thread():
                raise RuntimeError("inside")
        except RuntimeError:
            pass
        assert set(_blas_threads()) == {3}


@pytest.mark.slow
def test_detection_runs_with_one_blas_thread_and_gives_the_limit_back(monkeypatch, library, synth_small):
    """Detector.detect does its work under the limit (seen from inside its grouping stage) and returns BLAS to
    the threads it had."""
    from pcdet.config import PipelineConfig
    from pcdet.datasets.bop import BopDataset
    from pcdet.detector import Detector

    ds = BopDataset(synth_small)
    ref = next(iter(ds))
    det = Detector(library, PipelineConfig(), workers=1)
    inside: list[list[int]] = []
    group = det.grouper.group

    def spy(*args, **kwargs):
        inside.append(_blas_threads())
        return group(*args, **kwargs)

    monkeypatch.setattr(det.grouper, "group", spy)
    with threadpool_limits(3, user_api="blas"):
        det.detect(ds.frame(ref), ds.targets(ref))
        assert inside and all(set(t) == {1} for t in inside)
        assert set(_blas_threads()) == {3}


def _spy(monkeypatch, owner, name: str, seen: list) -> None:
    """Replace ``owner.name`` by a wrapper that records the BLAS thread counts each time it is called."""
    inner = getattr(owner, name)

    def spy(*args, **kwargs):
        seen.append(_blas_threads())
        return inner(*args, **kwargs)

    monkeypatch.setattr(owner, name, spy)


def test_registration_odometry_refinement_and_model_building_run_with_one_blas_thread(monkeypatch, library,
                                                                                     synth_small):
    """Every entry point that does many small products works under the limit (seen from a stage inside it) and
    returns BLAS to the threads it had: ``register``, ``Odometry.step``, ``Detector.refine``, ``build_model``, so
    that their results do not depend on how many threads BLAS would use."""
    import importlib

    from pcdet.config import PipelineConfig
    from pcdet.datasets.bop import BopDataset
    from pcdet.detector import Detector
    from pcdet.model import build_model
    from pcdet.odometry import Odometry
    from pcdet.register import register

    from .conftest import MODELS

    ds = BopDataset(synth_small)
    ref = next(iter(ds))
    frame = ds.frame(ref)
    det = Detector(library, PipelineConfig(), workers=1)
    gt = ds.gt(ref)[0]
    seen: dict[str, list] = {"register": [], "odometry": [], "refine": [], "build": []}
    module = importlib.import_module  # ``pcdet.register`` the attribute is the function, not its module
    _spy(monkeypatch, module("pcdet.register"), "icp", seen["register"])
    _spy(monkeypatch, module("pcdet.odometry"), "icp", seen["odometry"])
    _spy(monkeypatch, det, "_icp", seen["refine"])
    _spy(monkeypatch, module("pcdet.model"), "view_features", seen["build"])
    model = library[library.index_of(gt["obj_id"])]
    with threadpool_limits(3, user_api="blas"):
        register(model.points, model.points[::2] + 0.01, units="m")
        odo = Odometry()
        odo.step(frame)
        odo.step(frame)
        det.refine(frame, library.index_of(gt["obj_id"]), gt["T_cam_model"])
        build_model(sorted(MODELS.glob("*.ply"))[0], PipelineConfig())
        assert set(_blas_threads()) == {3}
    for name, counts in seen.items():
        assert counts, f"{name}: the spied stage was never reached"
        assert all(set(c) == {1} for c in counts), f"{name}: BLAS threads inside {counts}"
