"""The API: FastAPI app (routes over core services), its CLI and the serving of the dashboard. Imports no Celery task
code and no OpenCV (tests/test_layers.py)."""

from fringelab import __version__

__all__ = ["__version__"]
