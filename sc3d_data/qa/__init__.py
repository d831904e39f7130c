"""Quality checks and pictures of a finished dataset: mask/voxel agreement (``check``), contact sheets
and voxel previews (``preview``), index summaries (``index_report``)."""
