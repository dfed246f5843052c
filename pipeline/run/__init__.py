"""A run's parts below the command line: drawing frames (`frames`), writing outputs
atomically (`outputs`), progress bars, signals, the first run's two-process compile
(`warmup`) and the usage error.

May import: pipeline.simulation and every layer below it, shading, clothjit.
"""
