"""Solid voxelization of (possibly open) meshes: ``voxelize`` (public API) over numba kernels
(``_kernels``)."""
