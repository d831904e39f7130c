"""Files: mesh loading (``meshes``), binvox (``binvox``), the HDF5 shard format and its one reader and
writer (``shards``, ``shard_reader``), and the output-folder lock (``outlock``)."""
