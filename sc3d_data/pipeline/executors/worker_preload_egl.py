"""``worker_preload`` plus PyOpenGL with pyrender's EGL platform, for a forkserver whose workers
render with EGL (see ``worker_preload`` and ``local_pool.worker_context``)."""
import gc

from sc3d_data.pipeline.executors.worker_preload import best_effort, import_gl

best_effort(import_gl, "egl")
gc.freeze()
