"""Perception in the loop: a rendered camera, an IMU and an MSCKF visual-inertial estimator.

One concept per module: :mod:`.options` (every parameter), :mod:`.geometry` (SO(3)),
:mod:`.texture` (seeded procedural textures), :mod:`.world` (textured planes and their
homographies), :mod:`.render` (image formation), :mod:`.imu` (gyroscope and accelerometer),
:mod:`.tracker` (FAST + KLT + RANSAC), :mod:`.msckf` (the filter), :mod:`.loop` (the camera
VIO the closed loop calls, and a replay of a recorded trajectory). Design: ``docs/camera.md``.
"""
