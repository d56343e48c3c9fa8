"""Compiled (numba) kernels of the hot paths: plant rigid body, EKF, allocation, controller, waves.

Each kernel is the NumPy implementation it replaces written in scalars and loops, compiled once and
cached on disk (``_jit.py``); ``tests/test_kernels.py`` holds each equal to the NumPy form.
"""
