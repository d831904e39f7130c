"""Every training setting, declared once as typed dataclasses with defaults and help
(``config``: ``fit``; ``command_config``: ``eval``, ``predict``, ``claims``; ``config_io``:
declarations, YAML, checks). Imports no other part of sc3d_train and nothing heavy (no torch), so
``--help`` stays fast."""
