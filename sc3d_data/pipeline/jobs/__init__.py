"""The jobs: what happens to one object (render, import a 3D-R2N2 model, voxelize) and the run
of each over its plan, with its SLURM entry. The top of the pipeline: imports ``run`` and
``executors`` (``sc3d_data.pipeline``)."""
