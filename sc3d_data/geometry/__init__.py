"""Conventions and pure geometry: cameras and PTN poses (``camera``), the voxel grid's index <-> world
map (``voxel_grid``), mesh normalisation into the canonical frame (``normalize``) and the exact
projection of voxels into a view (``projection``). Imports nothing else of sc3d_data."""
