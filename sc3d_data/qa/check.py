"""``sc3d-data check``: do renderer, voxelizer and cameras agree?

For every object and view the occupied voxels are projected through the stored camera
(``sc3d_data.geometry.projection``, voxels as cubes) and compared with the rendered mask:

- ``coverage``: |mask AND projected| / |mask|, the share of rendered pixels the voxels cover;
- ``near``: the share of projected-voxel pixels that lie within one voxel's projected
  diagonal (+1 pixel) of a mask pixel, not counting excess narrower than a voxel
  (:func:`near_score`);
- ``iou``: |mask AND projected| / |mask OR projected| (reported; judged only when
  ``min_iou`` > 0).

An object's scores are the means over its views. The report gives mean/min per category and
the worst objects; ``write_worst_png`` draws image | mask | projected voxels | difference for
the worst views. The check fails when any object's mean coverage is below ``min_coverage``,
its mean ``near`` below ``min_near`` or its mean IoU below ``min_iou``.

Why these two: both are 1.000 for a consistent dataset *by construction*, whatever the
object's shape. Coverage: the occupancy rule makes every rendered pixel fall inside a
projected voxel (the surface point seen there lies in an occupied voxel). Near: every occupied
voxel touches the surface or is enclosed by it, so each point of its projected cube is at most
one projected cube diagonal away from the projection of a surface point, i.e. a mask pixel;
the one exception, structures thinner than a pixel that the point-sampled mask misses
(a lamp's wire), leaves excess only one voxel wide, which ``near`` does not count.
Coverage catches voxels that miss the object (wrong frame, axes, camera: voxels rotated 90
degrees about +Y score 0.40 to 0.88 on the bundled meshes); near catches voxels that stick out
by more than a voxel (grid too large, shifted, wrong camera distance). IoU cannot be such a
test: voxel cubes stick out of the surface by up to a voxel, and structures thinner than a
voxel (lamp arms, chandeliers, chair legs, glider wings) are present as whole voxels but only
as thin lines in the mask, so a correct thin object can score IoU 0.2 while a bulky one
scores 0.9.

A view whose camera has occupied voxels behind it (a ``--distance`` under sqrt(3)/2 that an
earlier sc3d accepted) has no silhouette to compare: it scores 0 on all three (so its object
fails) and the report names the object and its views; the check goes on with the others.
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sc3d_data.geometry.projection import project_voxels_views
from sc3d_data.io.drawn_names import mpl_name
from sc3d_data.io.failed_grids import voxelize_failures
from sc3d_data.io.names import printable, shell_word
from sc3d_data.io.pictures import write_figure
from sc3d_data.io.shard_reader import ShardReader, iter_objects, verify_shards
from sc3d_data.io.shards import ShardError, load_index, shard_path
from sc3d_data.formats.shapenet import category_label

DEFAULT_MIN_IOU = 0.0
DEFAULT_MIN_COVERAGE = 0.98
DEFAULT_MIN_NEAR = 0.98


@dataclass
class ObjectScore:
    category: str
    model_id: str
    shard: str
    row: int
    iou: np.ndarray        # [V] per view
    coverage: np.ndarray   # [V] per view
    near: np.ndarray       # [V] per view
    behind: tuple[int, ...] = ()  # views with occupied voxels behind the camera (scored 0)

    @property
    def mean_iou(self) -> float:
        return float(self.iou.mean())

    @property
    def worst_view(self) -> int:
        """The view with the lowest of coverage and near (ties: lowest IoU)."""
        return int(np.lexsort((self.iou, np.minimum(self.coverage, self.near).round(3)))[0])

    @property
    def mean_coverage(self) -> float:
        return float(self.coverage.mean())

    @property
    def mean_near(self) -> float:
        return float(self.near.mean())


@dataclass
class CheckReport:
    objects: list[ObjectScore] = field(default_factory=list)
    #: ``category/model_id`` of the objects left out: their voxelization failed (``io.failed_grids``)
    left_out: list[str] = field(default_factory=list)
    min_iou: float = DEFAULT_MIN_IOU
    min_coverage: float = DEFAULT_MIN_COVERAGE
    min_near: float = DEFAULT_MIN_NEAR

    def per_category(self) -> dict[str, dict]:
        groups = defaultdict(list)
        for o in self.objects:
            groups[o.category].append(o)
        return {c: {"objects": len(v), "mean_iou": float(np.mean([o.mean_iou for o in v])),
                    "min_iou": float(np.min([o.mean_iou for o in v])),
                    "mean_coverage": float(np.mean([o.mean_coverage for o in v])),
                    "min_coverage": float(np.min([o.mean_coverage for o in v])),
                    "min_near": float(np.min([o.mean_near for o in v]))}
                for c, v in sorted(groups.items())}

    def worst(self, n: int = 10) -> list[ObjectScore]:
        return sorted(self.objects, key=lambda o: (round(min(o.mean_coverage, o.mean_near), 3), o.mean_iou))[:n]

    @property
    def failing(self) -> list[ObjectScore]:
        return [o for o in self.objects
                if o.mean_iou < self.min_iou or o.mean_coverage < self.min_coverage
                or o.mean_near < self.min_near]

    @property
    def passed(self) -> bool:
        return bool(self.objects) and not self.failing

    def text(self, n_worst: int = 10) -> str:
        lines = [f"{'category':<22} {'objects':>7} {'mean IoU':>9} {'min IoU':>8} {'mean cov':>9} {'min cov':>8} "
                 f"{'min near':>8}"]
        rows = list(self.per_category().items())
        if self.objects:
            rows.append(("all", {"objects": len(self.objects),
                                 "mean_iou": float(np.mean([o.mean_iou for o in self.objects])),
                                 "min_iou": min(o.mean_iou for o in self.objects),
                                 "mean_coverage": float(np.mean([o.mean_coverage for o in self.objects])),
                                 "min_coverage": min(o.mean_coverage for o in self.objects),
                                 "min_near": min(o.mean_near for o in self.objects)}))
        for c, s in rows:
            lines.append(f"{printable(category_label(c)):<22} {s['objects']:>7} {s['mean_iou']:>9.3f} {s['min_iou']:>8.3f} "
                         f"{s['mean_coverage']:>9.3f} {s['min_coverage']:>8.3f} {s['min_near']:>8.3f}")
        lines.append("worst objects (mean coverage, near, IoU over views; worst view and its IoU):")
        for o in self.worst(n_worst):
            lines.append(f"  cov {o.mean_coverage:.3f}  near {o.mean_near:.3f}  IoU {o.mean_iou:.3f}  view {o.worst_view:>2} "
                         f"{o.iou[o.worst_view]:.3f}  {printable(f'{o.category}/{o.model_id}')}  ({o.shard} row {o.row})")
        for o in (o for o in self.objects if o.behind):
            lines.append(f"  {printable(f'{o.category}/{o.model_id}')} ({o.shard} row {o.row}): view(s) "
                         f"{', '.join(map(str, o.behind))} have voxels behind the camera (its distance is under "
                         "sqrt(3)/2); scored 0")
        verdict = "PASS" if self.passed else "FAIL"
        iou_rule = f" or min IoU {self.min_iou}" if self.min_iou > 0 else ""
        lines.append(f"{verdict}: {len(self.failing)} of {len(self.objects)} objects below min coverage "
                     f"{self.min_coverage} or min near {self.min_near}{iou_rule}")
        return "\n".join(lines)


def voxel_footprint(voxels: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> float:
    """Pixels one voxel's cube diagonal (``sqrt(3)/G``) spans at the nearest occupied voxel
    (units: pixels of ``K``): how far a correct voxel's projection may reach from the surface."""
    from sc3d_data.geometry.camera import world_to_camera
    from sc3d_data.geometry.voxel_grid import voxel_centres, voxel_size

    G = voxels.shape[0]
    centres = voxel_centres(np.argwhere(voxels), G)
    if not len(centres):
        return 1.0
    diag = np.sqrt(3.0) * voxel_size(G)
    z_near = max(float(world_to_camera(centres, R, t)[:, 2].min()) - diag / 2, 1e-6)
    return float(K[0, 0]) * diag / z_near


def near_score(mask: np.ndarray, projected: np.ndarray, footprint: float) -> float:
    """``near`` of one view (module doc): 1 - the share of projected pixels farther than
    ``footprint + 1`` pixels from the mask *in regions wider than a voxel* (a morphological
    opening with a square of side ``ceil(footprint) + 1``, odd, drops the one-voxel-wide
    excess of structures thinner than a pixel, e.g. a lamp's wire, that the point-sampled mask
    misses while the voxels keep them). A footprint beyond the image (a voxel next to the
    camera) counts as the image's size: no distance in it is larger."""
    from scipy.ndimage import binary_opening, distance_transform_edt

    footprint = min(footprint, float(sum(mask.shape)))

    if not projected.any():
        return 1.0
    # an empty mask (a flat object seen edge-on) leaves every projected pixel far from it
    far = projected & (distance_transform_edt(~mask) > footprint + 1.0) if mask.any() else projected
    k = int(np.ceil(footprint)) + 1
    k += 1 - k % 2
    wide = binary_opening(far, structure=np.ones((k, k), bool))
    return 1.0 - float(wide.sum()) / float(projected.sum())


def view_scores(voxels: np.ndarray, masks: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                behind: list[int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(iou [V], coverage [V], near [V])`` of one object's ``voxels [G,G,G]`` against
    ``masks [V,S,S]`` with cameras ``K [V,3,3]``, ``R [V,3,3]``, ``t [V,3]`` (module doc).
    Empty mask and projection: 1. A view with voxels behind its camera scores 0 and is
    appended to ``behind``."""
    S = masks.shape[-1]
    iou, cov, near = np.empty(len(masks)), np.empty(len(masks)), np.empty(len(masks))
    vox = np.asarray(voxels).astype(bool)
    behind = [] if behind is None else behind
    projected = project_voxels_views(vox, K, R, t, S, range(len(masks)), behind)
    for v in range(len(masks)):
        m, p = masks[v].astype(bool), projected[v]
        if v in behind:
            iou[v] = cov[v] = near[v] = 0.0
            continue
        inter, union = (m & p).sum(), (m | p).sum()
        iou[v] = inter / union if union else 1.0
        cov[v] = inter / m.sum() if m.sum() else 1.0
        near[v] = near_score(m, p, voxel_footprint(vox, K[v], R[v], t[v]))
    return iou, cov, near


def check_shards(shard_dir: Path, min_iou: float = DEFAULT_MIN_IOU,
                 min_coverage: float = DEFAULT_MIN_COVERAGE, progress: bool = False,
                 min_near: float = DEFAULT_MIN_NEAR) -> CheckReport:
    """Score every object of the shards in ``shard_dir`` (module doc). The shards are verified
    against the index checksums first (a corrupted image fails the check even though only
    masks and voxels are scored): ``ShardError`` naming the first broken shard. Objects whose
    voxelization failed (an empty placeholder grid, ``io.failed_grids``) are left out and
    listed in ``left_out``: their failure is in the index, not a disagreement to find."""
    broken = verify_shards(shard_dir)
    if broken:
        more = f" (and {len(broken) - 1} more; `sc3d-data info --verify {shard_dir}` lists them)" if len(broken) > 1 else ""
        raise ShardError(broken[0] + more)
    report = CheckReport(min_iou=min_iou, min_coverage=min_coverage, min_near=min_near)
    failed = voxelize_failures(load_index(shard_dir))
    it = iter_objects(shard_dir, fields=("voxels", "masks", "K", "R", "t"))
    if progress:
        from sc3d_data.pipeline.run.progress import progress_bar

        it = progress_bar(it, unit="obj", desc="check")
    for obj in it:
        if (obj["shard"], obj["row"]) in failed:  # an empty placeholder grid: nothing to check
            report.left_out.append(f"{obj['category']}/{obj['model_id']}")
            continue
        if "voxels" not in obj:
            raise ValueError(f"{shard_dir}/{obj['shard']}: no voxels (run `sc3d-data voxelize {shell_word(shard_dir)}` first)")
        behind: list[int] = []
        iou, cov, near = view_scores(obj["voxels"], obj["masks"], obj["K"], obj["R"], obj["t"], behind)
        report.objects.append(ObjectScore(obj["category"], obj["model_id"], obj["shard"], obj["row"], iou, cov,
                                          near, tuple(behind)))
    return report


def write_worst_png(shard_dir: Path, report: CheckReport, path: Path, n: int = 8) -> Path:
    """PNG with one row per worst object (its worst view): image | mask | projected voxels,
    plus a fourth panel showing their difference (green = both, red = mask only,
    blue = voxels only). The image's title names the object as the text report does,
    ``category/model_id`` (one model id can be in two categories), written by
    ``io.drawn_names.mpl_name`` (what the font cannot draw as ``\\uXXXX``, cut with ``...`` to its
    column), then its worst view and scores."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    worst = report.worst(n)
    if not worst:
        raise ValueError("no objects to draw")
    fig, axes = plt.subplots(len(worst), 4, figsize=(8, 2.1 * len(worst)), squeeze=False)
    name_pt = 0.9 * 8 / 4 * 72  # a column's width: a longer name ran off the picture's left edge
    reader = ShardReader(shard_dir)
    for r, o in enumerate(worst):
        v = o.worst_view
        obj = reader.read(shard_path(shard_dir, o.shard), o.row, ("images", "masks", "voxels", "K", "R", "t"))
        image, mask = obj["images"][v], obj["masks"][v].astype(bool)
        # a view with voxels behind its camera is drawn empty; the report names it
        proj = project_voxels_views(obj["voxels"], obj["K"], obj["R"], obj["t"], mask.shape[-1], [v], [])[0]
        diff = np.zeros(mask.shape + (3,))
        diff[mask & proj] = (0, 0.8, 0)
        diff[mask & ~proj] = (1, 0, 0)
        diff[~mask & proj] = (0.2, 0.4, 1)
        for c, (img, title) in enumerate([(image, "image"), (mask, "mask"), (proj, "voxels"),
                                          (diff, "diff")]):
            ax = axes[r, c]
            ax.imshow(img, cmap="gray" if img.ndim == 2 else None, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(title if c else f"{mpl_name(f'{o.category}/{o.model_id}', name_pt, 7)}\n"
                         f"v{v} cov {o.coverage[v]:.2f} IoU {o.iou[v]:.2f}", fontsize=7, parse_math=False)
    reader.close()
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_figure(fig, path, dpi=100)
    plt.close(fig)
    return path
