"""Jobs over many objects: rendering and voxelizing a folder of meshes into shards, with resume,
failure records and progress (``progress``)."""
