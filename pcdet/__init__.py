"""pcdet: find known rigid objects in depth data and estimate their 6-DoF poses, with classical geometry.

A tour (the sample models ship with the package; data in memory works where paths do)::

    >>> import pcdet
    >>> lib = pcdet.ModelLibrary.from_folder(pcdet.resources.shipped("models"))   # or .from_objects({...})
    >>> det = pcdet.Detector(lib, pcdet.load_pipeline("default"))                 # presets: pipelines/*.toml
    >>> frame = pcdet.Frame.from_depth_png("depth.png", "camera.json")            # or Frame.from_cloud(points)
    >>> result = det.detect(frame)                                                # DetectionResult
    >>> [(d.model, d.score, d.T_cam_model) for d in result.detections]            # poses: 4x4, metres
    >>> pcdet.register("model.ply", "scan.ply").T_target_source                   # model to scan, no guess

Frame: depth (m) + Camera; ModelLibrary: meshes or clouds, cached descriptors; Detector: the pipeline, built
from a PipelineConfig (load_pipeline, or PipelineConfig().replace(...)); register: global alignment + ICP.
Recordings, tracking, synthetic data and the BOP metrics are in pcdet.runner, pcdet.tracking, pcdet.synth
and pcdet.evaluate; the command line is ``pcdet --help``. Units: metres; poses are T_<to>_<from>.
"""
from __future__ import annotations

import importlib
import sys
import types

__version__ = "0.1.0"

# The public names and the module each lives in: imported on first use (PEP 562), so that ``import pcdet`` and the
# command's start stay cheap and a command loads only the stages it runs.
_PUBLIC = {"Camera": "camera", "Frame": "frame", "ModelLibrary": "library", "ObjectModel": "model",
           "Detector": "detector", "Detection": "detector", "DetectionResult": "detector",
           "PipelineConfig": "config", "load_pipeline": "config", "register": "register",
           "Registration": "register", "RegisterConfig": "register", "InputError": "errors"}

__all__ = list(_PUBLIC) + ["__version__"]


def __getattr__(name: str):
    if name in _PUBLIC:
        value = getattr(importlib.import_module(f".{_PUBLIC[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pcdet' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))


class _Package(types.ModuleType):
    """Importing the submodule ``pcdet.register`` binds the package's ``register`` to that module; the public
    ``pcdet.register`` is the function, as the eager imports of earlier versions left it."""

    def __setattr__(self, name, value):
        if name == "register" and isinstance(value, types.ModuleType):
            value = value.register
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
