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
from .camera import Camera
from .config import PipelineConfig, load_pipeline
from .detector import Detection, DetectionResult, Detector
from .errors import InputError
from .frame import Frame
from .library import ModelLibrary
from .model import ObjectModel
from .register import RegisterConfig, Registration, register

__version__ = "0.1.0"

__all__ = ["Camera", "Frame", "ModelLibrary", "ObjectModel", "Detector", "Detection", "DetectionResult",
           "PipelineConfig", "load_pipeline", "register", "Registration", "RegisterConfig", "InputError",
           "__version__"]
