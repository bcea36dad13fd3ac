"""Files below the detector: atomic outputs, image files, the shared data folder.

Imports only :mod:`fastdet.errors` (and OpenCV for images), so every layer
above may use it.
"""
