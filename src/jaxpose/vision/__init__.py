"""Image-side steps (NumPy + OpenCV), one file a step; see each module."""
