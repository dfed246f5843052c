"""Dask distributed: connecting (`client`: --workers / --scheduler, the worker plugin) and
one long render split into a simulation task and rendering tasks (`farm`). Imported only
when a cluster is asked for.

May import: pipeline.run and every layer below it; never the command line (pipeline.cli).
"""
