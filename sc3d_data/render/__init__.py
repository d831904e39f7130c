"""Offscreen rendering: choosing and activating EGL or OSMesa (``gl_backend``), the instanced mesh
renderer (``renderer``) and the one-triangle probe that checks a backend works (``probe``)."""
