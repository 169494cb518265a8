"""fringelab's web side: FastAPI app, CLI, settings, database. Imports no Celery task code and no OpenCV."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("fringelab")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
