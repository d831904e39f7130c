"""The paper's method: the network (``model``), its pose grid (``pose``), the differentiable ray
consistency (``self_consistency``), the pose search (``pose_search``), the losses (``losses``) and
the metrics (``metrics``). Imports ``settings`` only (and ``sc3d_data.geometry``)."""
