"""Dataset layouts: ShapeNetCore folders and ids (``shapenet``), finding meshes in a folder
(``discover``), train/val/test assignment (``splits``) and the 3D-R2N2 release (``r2n2``)."""
