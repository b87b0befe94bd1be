"""The simulator: RotorPy vehicle, VIO emulator, motion capture, references, controllers.

Entry point :func:`qsls.pipeline.sim.simulate.simulate` (imported lazily so that
``qsls.pipeline.sim.vio`` stays light).
"""
