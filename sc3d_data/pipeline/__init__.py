"""Running the per-object data jobs (render, voxelize, import) on one machine or many.

Modules, one job each:

- ``render_job``: settings of a render run and the work on one object (``render_task``);
- ``plan`` / ``partition``: which objects a run (or part ``I/N`` of a run) handles;
- ``job``: what a worker runs per object (``Job``: render, import, voxelize a mesh) and the
  options every job's run shares (``ExecOptions``: executor, workers, timeout, Ray address);
- ``executor``: the interface of an executor (run a job per object with a time limit, yield
  ``(pos, status, payload)``) and ``--executor``'s choice;
- ``local_pool`` / ``ray_executor``: the two executors;
- ``slurm_executor``: a job array of parts through submitit, then ``merge`` (render, import;
  ``voxelize --meshes`` parts share one folder);
- ``render_run``: the render driver (plan, executor, summary);
- ``shard_output``: the one chunk loop and index writer of every job that writes shards
  (render, import, voxelize SHARDS), holding the output lock;
- ``resume``: what an existing index lets a rerun keep;
- ``merge``: part folders -> one dataset;
- ``voxel_job``: ``sc3d-data voxelize SHARDS``; ``voxel_meshes``: ``voxelize --meshes``;
- ``r2n2_job``: ``sc3d-data import-r2n2`` (plan, shards and index, resume).
"""
