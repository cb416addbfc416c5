"""Applications: the monocular initialisation (and, beside it, the stereo tracking) pipelines."""
