"""fidelity auto: model no more than a scene needs, within a tolerance in pixels.

- `controller`: the frame-by-frame step controller (AutoStepper), sleeping, the pilots;
- `plan`: what will be modelled and why (`render plan`), the integrator's choice;
- `fem_grid`: the FEM grid chosen by a pilot on coarser grids;
- `reach`: skipping self-collision and colliders exactly where nothing can touch;
- `overlap`: points that start inside a collider, moved out.

May import: pipeline.view, pipeline.physics, pipeline.scene, clothjit. The Simulation that
drives it sits above (pipeline.simulation) and hands itself in.
"""
