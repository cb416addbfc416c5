"""File I/O: camera files, SPEED+ labels, images. The one place for frame conversions of files."""

from jaxpose.io.camera_file import load_camera as load_camera
from jaxpose.io.camera_file import save_camera as save_camera
from jaxpose.io.image import load_image as load_image
from jaxpose.io.software import software_versions as software_versions
from jaxpose.io.speedplus import SpeedLabel as SpeedLabel
from jaxpose.io.speedplus import load_speed_labels as load_speed_labels
from jaxpose.io.speedplus import speed_label_pose as speed_label_pose

__all__ = [
    "SpeedLabel",
    "load_camera",
    "load_image",
    "load_speed_labels",
    "save_camera",
    "software_versions",
    "speed_label_pose",
]
