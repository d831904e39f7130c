"""``sc3d-data``: meshes -> rendered views, voxels and HDF5 shards."""
from sc3d_cli.lazy_group import lazy_main

COMMANDS = {
    "render": "sc3d_cli.data_render:render",
    "info": "sc3d_cli.data_info:info",
    "preview": "sc3d_cli.data_preview:preview",
    "voxelize": "sc3d_cli.data_voxelize:voxelize",
    "check": "sc3d_cli.data_check:check",
    "import-r2n2": "sc3d_cli.data_import_r2n2:import_r2n2",
    "merge": "sc3d_cli.data_merge:merge",
}


main = lazy_main(COMMANDS, """Turn a folder of 3D meshes into training data: rendered views with explicit cameras,
    silhouette masks and solid voxel grids, in HDF5 shards (see SPEC.md).""")
