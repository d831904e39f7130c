"""sc3d_data: meshes -> rendered views, masks, voxels and cameras in HDF5 shards."""
