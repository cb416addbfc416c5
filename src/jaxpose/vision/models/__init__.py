"""Spacecraft wireframe models (vision layer: NumPy, files).

:class:`WireframeModel` holds vertices, edges, faces (for visibility) and antenna segments;
:func:`tango` is the built-in Tango model; :func:`load_model` reads the JSON format of
:mod:`jaxpose.vision.models.wireframe` or a mesh (STL/OBJ/PLY through ``trimesh``).
Model feature groups (same rules as the image's) are in :mod:`jaxpose.vision.models.groups`.
"""

from jaxpose.vision.models.groups import ModelGroups as ModelGroups
from jaxpose.vision.models.groups import model_groups as model_groups
from jaxpose.vision.models.wireframe import WireframeModel as WireframeModel
from jaxpose.vision.models.wireframe import load_model as load_model
from jaxpose.vision.models.wireframe import load_model_json as load_model_json
from jaxpose.vision.models.wireframe import load_model_mesh as load_model_mesh
from jaxpose.vision.models.wireframe import tango as tango

__all__ = [
    "ModelGroups",
    "WireframeModel",
    "load_model",
    "load_model_json",
    "load_model_mesh",
    "model_groups",
    "tango",
]
