"""pcdet.blas: BLAS limited to one thread while pcdet works, and restored afterwards."""
from __future__ import annotations

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
