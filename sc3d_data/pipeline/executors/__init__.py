"""Where and how long each object runs: the job contract (``job``), the executor interface
(``executor``), the local pool, Ray and SLURM. Imports ``run`` (``Task``, ``Part``), never a job:
the job to run is passed in (``sc3d_data.pipeline``)."""
