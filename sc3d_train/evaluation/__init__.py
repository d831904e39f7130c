"""Measuring and using a trained model: ``eval`` (``evaluate``), ``predict`` and the ``claims``
study (``claims``, ``claims_report``). The top of sc3d_train: may import every other folder."""
