"""Running the per-object data jobs (render, voxelize, import) on one machine or many.

Modules, one job each:

- ``render_job``: settings of a render run and the work on one object (``render_task``);
- ``plan`` / ``partition``: which objects a run (or part ``I/N`` of a run) handles;
- ``executor``: the interface of an executor (run ``render_task`` per object with a time limit,
  yield ``(pos, status, payload)``) and ``--executor``'s choice;
- ``local_pool`` / ``ray_executor``: the two executors;
- ``slurm_executor``: a job array of parts through submitit, then ``merge``;
- ``render_run``: the render driver (chunks, shards and index in plan order);
- ``resume``: what an existing index lets a rerun keep;
- ``merge``: part folders -> one dataset;
- ``voxel_job``: ``sc3d-data voxelize``.
"""
