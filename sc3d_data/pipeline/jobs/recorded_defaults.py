"""What a setting that an older sc3d did not record in ``index.json`` stands for, given the
settings the index does record: the defaults of the command that made it (``render``'s
:class:`~sc3d_data.pipeline.jobs.render_job.RenderConfig`, ``import-r2n2``'s
:class:`~sc3d_data.pipeline.jobs.r2n2_job.ImportConfig`; ``setting_meaning.config_defaults``).
``sc3d-data merge`` compares parts, and an ``OUT`` that holds a merge, through it: a part made
by an older sc3d merges with one made by a newer."""
from __future__ import annotations

from sc3d_data.pipeline.jobs.r2n2_job import ImportConfig
from sc3d_data.pipeline.jobs.render_job import RenderConfig
from sc3d_data.pipeline.run.setting_meaning import config_defaults


def recorded_defaults(settings: dict) -> dict:
    """The defaults of the command whose index records ``settings`` (by its ``source``)."""
    return config_defaults(ImportConfig if settings.get("source") == "3D-R2N2" else RenderConfig)
