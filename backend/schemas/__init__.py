"""Pydantic models of the API, one module per resource, kept apart from the database tables."""
