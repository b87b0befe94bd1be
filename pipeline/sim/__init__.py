"""The simulator: RotorPy vehicle, VIO emulator, motion capture, controllers (the
references they fly are :mod:`qsls.pipeline.core.references`).

Entry point :func:`qsls.pipeline.sim.simulate.simulate` (imported lazily so that
``qsls.pipeline.sim.vio`` stays light).
"""
