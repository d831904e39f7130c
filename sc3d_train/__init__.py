"""sc3d_train: the 2D-3D self-consistency model of Liao et al., trained on sc3d shards."""
