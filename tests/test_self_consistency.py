"""The 2D-3D self-consistency module: projections agree with the camera of the shards, L_sc is
lowest at the true pose, gradients reach voxels and pose."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import Delaunay

from sc3d_data.geometry.camera import extrinsics, intrinsics, project_points, scale_intrinsics
from sc3d_train.paper.pose import angular_error_deg
from drc_reference import project_occupancy_reference
from sc3d_train.paper.self_consistency import (area_downsample, project_occupancy, ray_cube_bounds,
                                               self_consistency_losses)

G, S = 32, 48
K48 = scale_intrinsics(intrinsics(64), S, 64)


def batch_k(b: int) -> torch.Tensor:
    return torch.as_tensor(K48, dtype=torch.float32).expand(b, 3, 3).contiguous()


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def box_grid(lo: tuple[int, int, int], hi: tuple[int, int, int]) -> torch.Tensor:
    occ = torch.zeros(G, G, G)
    occ[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = 1
    return occ


def asymmetric_object() -> torch.Tensor:
    """A 'chair': seat, a back on one side, one tall post at a corner (no mirror symmetry)."""
    occ = box_grid((6, 10, 6), (26, 14, 26))              # seat
    occ[6:26, 14:30, 6:10] = 1                             # back at -z
    occ[22:26, 0:10, 22:26] = 1                            # one leg at +x +z
    occ[6:9, 14:22, 18:26] = 1                             # arm at -x
    return occ


def box_silhouette(lo_idx, hi_idx, az: float, el: float) -> np.ndarray:
    """Analytic silhouette of a box of voxels: pixel centres inside the convex hull of the
    projected corners (the voxel cube edges are at -0.5 + i / G)."""
    lo = np.array(lo_idx) / G - 0.5
    hi = np.array(hi_idx) / G - 0.5
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
    R, t = extrinsics(az, el, 2.0)
    uv, depth = project_points(corners, K48, R, t)
    assert (depth > 0).all()
    g = np.arange(S) + 0.5
    v, u = np.meshgrid(g, g, indexing="ij")
    inside = Delaunay(uv).find_simplex(np.stack([u.ravel(), v.ravel()], -1)) >= 0
    return inside.reshape(S, S)


@pytest.mark.parametrize("az,el", [(0.0, 30.0), (37.0, 30.0), (135.0, 10.0), (290.0, 45.0)])
def test_box_projection_matches_analytic_silhouette(az, el):
    lo, hi = (4, 8, 10), (20, 28, 16)
    occ = box_grid(lo, hi)[None]
    proj, q = project_occupancy(occ, torch.tensor([az]), torch.tensor([el]), torch.tensor([2.0]), batch_k(1), S)
    assert proj.shape == (1, S, S) and q.shape == (1, S * S, 65)
    torch.testing.assert_close(q.sum(-1), torch.ones(1, S * S))
    got = proj[0].numpy() >= 0.5
    assert iou(got, box_silhouette(lo, hi, az, el)) >= 0.95


def test_axis_order_is_x_y_z():
    """A slab thin in x only looks thin from the front (az 0, camera on +Z: x is horizontal in the
    image) and wide from the side (az 90, camera on +X: z is horizontal). Catches a swapped
    (W, H, D) order in grid_sample."""
    occ = box_grid((14, 4, 2), (18, 28, 30))[None]
    one, k = torch.ones(1), batch_k(1)
    front, _ = project_occupancy(occ, 0 * one, 0 * one, 2 * one, k, S)
    side, _ = project_occupancy(occ, 90 * one, 0 * one, 2 * one, k, S)
    width = lambda p: int((p[0] >= 0.5).any(0).sum())  # noqa: E731  image columns covered
    assert width(front) <= 5 and width(side) >= 20
    # image "up" is world +Y: the object occupies y in [4, 28) of 32, so rows reach near the top
    rows = (front[0] >= 0.5).any(1).nonzero()[:, 0]
    assert abs(float(rows.float().mean()) - S / 2) < 6


def test_module_matches_straightforward_reference():
    torch.manual_seed(0)
    occ = torch.rand(2, G, G, G) * 0.2
    az, el = torch.tensor([10.0, 250.0]), torch.tensor([30.0, -20.0])
    d = torch.tensor([2.0, 2.5])
    fast, _ = project_occupancy(occ, az, el, d, batch_k(2), S)
    slow = project_occupancy_reference(occ, az, el, d, batch_k(2), S)
    torch.testing.assert_close(fast, slow, atol=2e-5, rtol=1e-4)


def test_rays_that_miss_the_cube_escape():
    near, far, hit = ray_cube_bounds(torch.tensor([[0.0, 0.0, 2.0]]),
                                     torch.tensor([[[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [0.2, 0.0, -0.9798]]]))
    assert hit.tolist() == [[True, False, True]]
    assert near[0, 0] == pytest.approx(1.5) and far[0, 0] == pytest.approx(2.5)
    full = torch.ones(1, G, G, G)
    proj, _ = project_occupancy(full, torch.zeros(1), torch.zeros(1), torch.full((1,), 2.0), batch_k(1), S)
    assert proj[0, 0, 0] < 1e-6 and proj[0, S // 2, S // 2] > 0.999  # corner pixel misses the cube


def test_area_downsample_keeps_area_and_alignment():
    m = torch.zeros(1, 64, 64)
    m[0, 16:48, 8:40] = 1  # 32x32 square at pixel edges 8..40 (x), 16..48 (y)
    d = area_downsample(m, 48)
    assert d.shape == (1, 48, 48)
    assert float(d.sum()) * (64 / 48) ** 2 == pytest.approx(float(m.sum()), rel=1e-5)
    cols = (d[0] >= 0.5).any(0).nonzero()[:, 0]
    # x edges 8, 40 at 64 px -> 6, 30 at 48 px
    assert cols.min() == 6 and cols.max() == 29


def sweep_losses(occ: torch.Tensor, target: torch.Tensor, azimuths: np.ndarray,
                 elevation: float = 30.0, distance: float = 2.0) -> np.ndarray:
    """L_sc = 5 L_ray + 0.125 L_proj of ``occ [G,G,G]`` vs ``target [S,S]`` at each azimuth."""
    el, d = torch.full((1,), elevation), torch.full((1,), distance)
    out = []
    for az in azimuths:
        sc = self_consistency_losses(occ[None], target[None], torch.tensor([float(az)]), el, d, batch_k(1))
        out.append(float(5 * sc["ray"] + 0.125 * sc["proj"]))
    return np.array(out)


def exact_silhouette(occ: torch.Tensor, azimuth: float, elevation: float = 30.0, distance: float = 2.0) -> torch.Tensor:
    """The voxel cubes' silhouette at 48 px by sc3d_data.geometry.projection (an independent
    rasteriser, not the module under test)."""
    from sc3d_data.geometry.projection import project_voxels

    R, t = extrinsics(np.float64(azimuth), np.float64(elevation), np.float64(distance))
    return torch.as_tensor(project_voxels(occ.numpy() > 0.5, K48, R, t, S), dtype=torch.float32)


def test_sc_loss_lowest_at_true_azimuth_synthetic():
    occ = asymmetric_object()
    azimuths = np.arange(0, 360, 15.0)
    for true_az in (45.0, 210.0):
        losses = sweep_losses(occ, exact_silhouette(occ, true_az), azimuths)
        assert azimuths[int(np.argmin(losses))] == true_az
        assert losses.min() < 0.5 * np.median(losses)
    # negative control: the mirrored camera (azimuth -> -azimuth) is not the minimum
    losses = sweep_losses(occ, exact_silhouette(occ, 45.0), azimuths)
    assert losses[list(azimuths).index(315.0)] > losses.min() + 0.05


def test_gradients_reach_voxels_and_pose_and_point_to_the_truth():
    occ = asymmetric_object()[None]
    d = torch.full((1,), 2.0)
    target = exact_silhouette(occ[0], 60.0)[None]
    az = torch.tensor([70.0], requires_grad=True)
    elev = torch.tensor([30.0], requires_grad=True)
    occ_g = (occ * 0.98 + 0.01).requires_grad_(True)
    out = self_consistency_losses(occ_g, target, az, elev, d, batch_k(1))
    (5 * out["ray"] + 0.125 * out["proj"]).backward()
    assert occ_g.grad.abs().sum() > 0 and elev.grad.abs() > 0
    assert az.grad.item() > 0  # decreasing the azimuth (towards the true 60 deg) lowers the loss


# ----------------------------------------------------------------------------- bundled meshes
@pytest.fixture(scope="module")
def shard_views(sample_shards):
    """Per bundled object: voxels, 48x48 rendered masks (area average >= 0.5) and the cameras."""
    from sc3d_data.io.shard_reader import iter_objects

    objs = []
    for obj in iter_objects(sample_shards, ("voxels", "masks", "K", "R", "t", "azimuth", "elevation", "distance")):
        masks = area_downsample(torch.as_tensor(obj["masks"], dtype=torch.float32), S) >= 0.5
        K = torch.as_tensor(scale_intrinsics(obj["K"].astype(np.float64), S, obj["masks"].shape[-1]),
                            dtype=torch.float32)
        objs.append({**obj, "masks48": masks, "K48": K})
    assert len(objs) == 11
    return objs


def project_views(obj: dict, azimuth=None) -> torch.Tensor:
    v = len(obj["azimuth"])
    az = torch.as_tensor(obj["azimuth"] if azimuth is None else azimuth, dtype=torch.float32)
    occ = torch.as_tensor(obj["voxels"], dtype=torch.float32)[None].expand(v, G, G, G)
    proj, _ = project_occupancy(occ, az, torch.as_tensor(obj["elevation"]), torch.as_tensor(obj["distance"]),
                                obj["K48"], S)
    return proj >= 0.5


def test_gt_voxels_reproduce_rendered_masks_with_gt_pose(shard_views):
    """Ground-truth voxels projected at the ground-truth pose of every view: they cover the
    rendered masks (camera, axes and pixel convention agree with the renderer), they match the
    exact voxel-cube silhouette of sc3d_data.geometry.projection (an independent rasteriser), and the
    overlap with the rendered mask is largest at the true azimuth. The IoU with the rendered mask
    itself is bounded by the voxelization (surface-touching voxels fatten thin parts: wings,
    legs), so it is asserted as a floor only (measured: 0.41 glider .. 0.90 armchair)."""
    from sc3d_data.geometry.projection import project_voxels

    ious = []
    for obj in shard_views:
        proj = project_views(obj)
        masks = obj["masks48"]
        coverage = float((proj & masks).sum() / masks.sum())
        assert coverage >= 0.98, (obj["model_id"], coverage)
        exact = torch.as_tensor(np.stack([project_voxels(obj["voxels"], obj["K48"][i].numpy(), obj["R"][i],
                                                         obj["t"][i], S) for i in range(0, 24, 6)]))
        assert iou(proj[::6].numpy(), exact.numpy()) >= 0.9, obj["model_id"]
        per_view = [iou(proj[i].numpy(), masks[i].numpy()) for i in range(len(masks))]
        shifted = project_views(obj, (np.asarray(obj["azimuth"]) + 15.0) % 360)
        per_view_shifted = [iou(shifted[i].numpy(), masks[i].numpy()) for i in range(len(masks))]
        assert np.mean(per_view) > np.mean(per_view_shifted) + 0.01, obj["model_id"]
        ious.append(np.mean(per_view))
    assert min(ious) >= 0.35 and np.mean(ious) >= 0.65, ious


def test_sc_loss_lowest_at_true_azimuth_on_rendered_chair(shard_views):
    """Sweep the azimuth of a real (asymmetric) object against one rendered mask: L_sc is lowest
    at the view's true azimuth."""
    chairs = [o for o in shard_views if "dining_chair" in o["model_id"] or "chair2" in o["model_id"]]
    assert len(chairs) == 2, [o["model_id"] for o in shard_views]
    for obj in chairs:
        for view in (3, 14):
            azimuths = np.arange(0, 360, 15.0)
            losses = sweep_losses(torch.as_tensor(obj["voxels"], dtype=torch.float32),
                                  obj["masks48"][view].float(), azimuths,
                                  float(obj["elevation"][view]), float(obj["distance"][view]))
            assert float(angular_error_deg(azimuths[int(np.argmin(losses))], float(obj["azimuth"][view]))) < 1


def test_pose_search_recovers_the_true_pose_of_rendered_objects(shard_views):
    """The pose search (L_sc of the ground-truth voxels at every candidate of the grid against the
    rendered mask; no start, no pose label) finds the shard's true azimuth exactly for the views
    of the asymmetric bundled objects (chairs, the jeep): measured 69 of 72 (the 3 others are
    front/back flips; chance is 3 of 72). Elevation is only weakly determined by a silhouette:
    the true 30 deg is the best of the 5 candidates 10..50 for 45 of 72 views (chance 14)."""
    from sc3d_train.paper.pose import PoseGrid
    from sc3d_train.paper.pose_search import search_losses_per_object

    objs = [o for o in shard_views if o["model_id"].startswith(("dining_chair", "jeep", "chair2"))]
    assert len(objs) == 3
    grid = PoseGrid()
    cand_az, cand_el = grid.candidates()
    exact_az, exact_el, total = 0, 0, 0
    for o in objs:
        masks = torch.as_tensor(o["masks"] > 0, dtype=torch.float32)
        losses = search_losses_per_object(torch.as_tensor(o["voxels"]).float(), masks, float(o["distance"][0]),
                                          torch.as_tensor(o["K"][0]), grid)
        best = losses.argmin(1)
        err = angular_error_deg(cand_az[best].numpy(), np.asarray(o["azimuth"], dtype=np.float64))
        exact_az += int((err < 1e-6).sum())
        exact_el += int((np.abs(cand_el[best].numpy() - np.asarray(o["elevation"])) < 1e-6).sum())
        total += len(err)
    assert total == 72
    assert exact_az >= 67, exact_az
    assert exact_el >= 40, exact_el


def test_test_time_search_recovers_the_azimuth_and_weighs_the_head_prior():
    """search_azimuth between a (here: true) occupancy and its exact silhouette at 45 deg finds
    candidate 3 (45 deg) at elevation bin 2 (30 deg) with no prior; a prior that puts all the
    head's probability on 90 deg with a huge weight overrides the search (the weight is what
    decides between them)."""
    from sc3d_train.paper.pose import PoseGrid
    from sc3d_train.paper.pose_search import search_azimuth

    grid = PoseGrid()
    occ = asymmetric_object()[None]
    mask = exact_silhouette(occ[0], 45.0)[None]
    K, d, e = batch_k(1), torch.full((1,), 2.0), torch.tensor([2])
    best = search_azimuth(occ, mask, d, K, grid, e, search_mask_size=24, num_samples=32)
    assert int(best) == 3 * 5 + 2
    log_p = torch.full((1, 24), -50.0)
    log_p[0, 6] = 0.0  # the head is sure of 90 deg
    assert int(search_azimuth(occ, mask, d, K, grid, e, prior_log_prob=log_p, prior_weight=0.0)) == 17
    assert int(search_azimuth(occ, mask, d, K, grid, e, prior_log_prob=log_p, prior_weight=1.0)) == 6 * 5 + 2
