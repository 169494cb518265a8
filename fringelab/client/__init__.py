"""A Python client of the fringelab server: `from fringelab.client import Client`.

Imports nothing of the server (only httpx and numpy), so a script needs only `pip install fringelab` (or this
folder) and a token. See `Client` for what it covers and `examples/automate.py` for a whole round trip.
"""

from fringelab.client.client import ApiError, Client, ClientError, Grid, JobFailed

__all__ = ["ApiError", "Client", "ClientError", "Grid", "JobFailed"]
