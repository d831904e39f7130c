"""Command-line entry points of sc3d (``sc3d-data`` and ``sc3d-train``)."""
