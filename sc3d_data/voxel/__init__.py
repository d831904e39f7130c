"""Solid voxelization of (possibly open) meshes: ``voxelize`` (public API) over numba kernels,
one private module per family (``_surface_kernel``, ``_ray_kernel``, ``_winding_kernels``,
``_fill_kernel``)."""
