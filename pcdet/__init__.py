"""pcdet: find known rigid objects in depth data and estimate their 6-DoF poses, with classical geometry."""
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
