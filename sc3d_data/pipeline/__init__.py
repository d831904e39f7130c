"""Running the per-object data jobs (render, voxelize, import) on one machine or many.

Three sub-packages, lowest first; a module imports its own folder and the folders before it only
(``tests/test_layout.py``):

- ``run``: run control every job shares: ``plan`` (``Task``, one object of a plan; the render
  plan), ``partition`` (which objects part ``I/N`` handles), ``resume`` (what an existing index
  lets a rerun keep), ``progress`` (objects/s, ETA), ``merge`` (part folders -> one dataset);
- ``executors``: where and how long each object runs: ``job`` (the contract: ``Job``, what a
  worker runs per object; ``ExecOptions``, the options every job's run shares; the worker
  environment), ``executor`` (the interface and ``--executor``'s choice), ``local_pool`` (with
  ``worker_preload``, ``worker_preload_egl`` and ``devices``), ``ray_executor`` and
  ``slurm_executor`` (a job array of parts through submitit);
- ``jobs``: what happens to one object and the run of a job over its plan: ``render_job`` and
  ``render_run`` (``sc3d-data render``), ``r2n2_job`` (``import-r2n2``), ``voxel_job``
  (``voxelize SHARDS``) and ``voxel_meshes`` (``voxelize --meshes``), each with its SLURM entry;
  ``shard_output``: the one chunk loop and index writer of every job that writes shards.

Adding an executor touches ``executors/`` only; adding a job, ``jobs/`` (and its CLI command).
"""
