"""Run control every job shares: the plan and its ``Task``, partitions (``--part I/N``), resume,
progress and merging part folders. Imports no executor and no job (``sc3d_data.pipeline``)."""
