"""The physics of the cloth: the model (data), its forces, constraints and contact, and one
module per integrator behind one interface.

- `model`: the cloth as flat arrays (points, springs, pins, masses), data only; `fem`: the
  finite-element energies; `forces`, `wind`, `constraints` (Provot's limit),
  `self_collision`, `colliders/` (one module per kind), `sdf` (mesh colliders' distance
  grids); `system`: the model packed for the kernels, the divergence guard and the
  stability limit; `integrators/`: one module per integrator; `errors`.

May import: pipeline.scene, clothjit (numba helpers); never the renderer (shading) or any
layer above (fidelity, simulation, run, cluster, cli). Enforced by import-linter.
"""
