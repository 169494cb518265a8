"""fringelab, the library: the measurement science, its file formats and the core shared by the API and the worker.

Layers, imports pointing one way only (tests/test_layers.py keeps it so):

    fringelab.science   pure numpy/OpenCV/SciPy: arrays and frozen dataclasses in and out
    fringelab.formats   one module per file type, its writer and reader together (numpy/h5py)
    fringelab.core      settings, database models, storage paths, job states, task names, job-spec types
    backend/ (the API)  and  worker/ (Celery tasks)  on top; they never import each other

The method these modules implement is described for users in docs/ (docs/method.md).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("fringelab")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
