"""How well the L_sc pose search determines the camera (the ceiling of what the pose head can learn
from it), per category, on the training split of a shard folder.

    python benchmarks/pose_search.py --shards SHARDS [--split train] [--mask-size 24] [--samples 32]
        [--azimuth-bins 24] [--elevation-bins 5] [--elevation-min 10] [--elevation-max 50]

For every object: its ground-truth voxels are projected at every candidate pose of the grid and
compared (L_sc) with each view's rendered mask; the best candidate is compared with the view's
true pose (read here only to score the search). Prints, per category: share of views whose best
azimuth is exact (< half a bin), within 30 deg, a front/back flip (>= 150 deg off); share of
exact elevations and the mean elevation error; and the time taken.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from sc3d_train.data.dataset import ShardDataset
from sc3d_train.paper.pose import PoseGrid, angular_error_deg
from sc3d_train.paper.pose_search import search_losses_per_object


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shards", required=True)
    ap.add_argument("--split", default="train")
    ap.add_argument("--mask-size", type=int, default=24)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--azimuth-bins", type=int, default=24)
    ap.add_argument("--elevation-bins", type=int, default=5)
    ap.add_argument("--elevation-min", type=float, default=10.0)
    ap.add_argument("--elevation-max", type=float, default=50.0)
    args = ap.parse_args()
    grid = PoseGrid(args.azimuth_bins, args.elevation_bins, args.elevation_min, args.elevation_max)
    ds = ShardDataset(args.shards, args.split)
    cand_az, cand_el = grid.candidates()
    per_cat: dict[str, list] = {}
    t0 = time.perf_counter()
    for i in range(ds.num_objects):
        a = ds.object_arrays(i)
        losses = search_losses_per_object(torch.as_tensor(a["voxels"]).float(),
                                          torch.as_tensor(a["masks"] > 0).float(), float(a["distance"][0]),
                                          torch.as_tensor(a["K"][0]), grid, search_mask_size=args.mask_size,
                                          num_samples=args.samples)
        best = losses.argmin(1)
        az_err = angular_error_deg(cand_az[best].numpy(), np.asarray(a["azimuth"], dtype=np.float64))
        el_err = np.abs(cand_el[best].numpy() - np.asarray(a["elevation"], dtype=np.float64))
        per_cat.setdefault(ds.objects[i].category, []).append((az_err, el_err))
    seconds = time.perf_counter() - t0
    half_bin = grid.azimuth_step / 2
    print(f"{grid}, {args.mask_size} px, {args.samples} samples/ray: {ds.num_objects} objects in {seconds:.1f} s")
    print(f"{'category':<12}{'views':>6}{'az exact':>10}{'az<=30':>8}{'flips':>7}{'el exact':>10}{'el err':>8}")
    for cat, rows in sorted(per_cat.items()):
        az = np.concatenate([r[0] for r in rows])
        el = np.concatenate([r[1] for r in rows])
        print(f"{cat:<12}{len(az):>6}{np.mean(az < half_bin):>10.2f}{np.mean(az <= 30):>8.2f}"
              f"{np.mean(az >= 150):>7.2f}{np.mean(el < 1e-6):>10.2f}{el.mean():>8.1f}")


if __name__ == "__main__":
    main()
