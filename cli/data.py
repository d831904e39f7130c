"""``sc3d-data``: meshes -> rendered views, voxels and HDF5 shards."""
import click

from cli.lazy_group import LazyGroup

COMMANDS = {
    "render": "cli.data_render:render",
    "info": "cli.data_info:info",
    "preview": "cli.data_preview:preview",
    "voxelize": "cli.data_voxelize:voxelize",
    "check": "cli.data_check:check",
    "import-r2n2": "cli.data_import_r2n2:import_r2n2",
    "merge": "cli.data_merge:merge",
}


@click.group(cls=LazyGroup, lazy_commands=COMMANDS)
@click.version_option(package_name="sc3d")
def main():
    """Turn a folder of 3D meshes into training data: rendered views with explicit cameras,
    silhouette masks and solid voxel grids, in HDF5 shards (see SPEC.md)."""
