"""sc3d_train: the 2D-3D self-consistency model of Liao et al., trained on sc3d shards.

Sub-packages, lowest first; a module imports its own folder and the folders before it only
(``tests/test_layout.py``): ``settings`` (every setting, declared once), ``paper`` (the network,
losses, pose search and metrics), ``data`` (shards to batches), ``loop`` (``fit`` and its run
state), ``evaluation`` (``eval``, ``predict``, ``claims``). See docs/ARCHITECTURE.md.
"""
