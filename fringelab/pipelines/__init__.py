"""Whole recordings from files to files: the runs the command line makes, and the reference for the worker's jobs.

Composed from the science stages (`fringelab.science`) and the file formats (`fringelab.formats`); no database,
queue or web code. One module per kind of run.
"""
