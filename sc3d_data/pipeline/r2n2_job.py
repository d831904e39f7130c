"""``sc3d-data import-r2n2`` as a library: 3D-R2N2's released renderings and voxels into sc3d
shards without re-rendering, optionally one part ``I/N`` of the models (``--part``).

The conventions (cameras, voxel placement, front axis, images) are ``sc3d_data.formats.r2n2``;
this module plans the models, assigns splits, converts each model into an
``sc3d_data.io.shards.ObjectRecord`` and writes shards and the index. A model that fails is
recorded in the index's ``failures`` with the reason and the others are imported.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from sc3d_data.formats.r2n2 import (BLENDER_LENS_MM, BLENDER_SENSOR_MM, MASK_THRESHOLD, R2N2_FOV_DEG, R2N2_FRONT,
                                    R2N2_NUM_VIEWS, R2N2_VOXEL_RESOLUTION, find_r2n2_models, load_r2n2_object)
from sc3d_data.pipeline.partition import Part


@dataclass
class ImportConfig:
    """Every option of ``sc3d-data import-r2n2`` (see ``cli/data_import_r2n2.py``)."""

    renderings: Path
    voxels: Path
    out: Path
    image_size: int = 64
    background: tuple[int, int, int] = (255, 255, 255)
    categories: str | None = None
    split: str = "r2n2"
    split_file: str | None = None
    seed: int = 0
    voxel_frame: str = "cube"
    front: str = R2N2_FRONT
    objects_per_shard: int = 256
    overwrite: bool = False
    part: Part = Part(0, 1)  # --part I/N (sc3d_data.pipeline.partition); 0/1 = all models

    def settings(self) -> dict:
        """JSON-able record of every setting (stored in the shards and the index)."""
        return {
            "source": "3D-R2N2", "renderings": str(Path(self.renderings).resolve()),
            "voxels": str(Path(self.voxels).resolve()), "image_size": int(self.image_size),
            "background": [int(c) for c in self.background], "categories": self.categories,
            "split": self.split, "split_file": self.split_file, "seed": int(self.seed),
            "voxel_frame": self.voxel_frame, "front": self.front, "objects_per_shard": int(self.objects_per_shard),
            "num_views": R2N2_NUM_VIEWS, "voxel_resolution": R2N2_VOXEL_RESOLUTION,
            "r2n2_camera": {"distance": "distance_ratio * 1.75", "lens_mm": BLENDER_LENS_MM,
                            "sensor_mm": BLENDER_SENSOR_MM, "fov_deg": R2N2_FOV_DEG,
                            "azimuth": "read from the canonical camera centre (front -> +Z)",
                            "roll": "-in_plane"},
            "mask": f"box-filtered alpha >= {MASK_THRESHOLD}",
        }


def _take_part(plan: list, part, problems: list, skipped: list):
    """This run's share of ``plan`` (``[(model, split)]``) for ``--part`` (all when None), the
    index's ``part`` record, and the problems/skipped files (reported by part 0 only)."""
    from sc3d_data.pipeline.partition import part_of, part_record, plan_digest

    part = part or Part(0, 1)
    digest = plan_digest((m.category, m.model_id, s) for m, s in plan)
    mine = [(m, s) for m, s in plan if part.whole or part_of(m.category, m.model_id, part.count) == part.index]
    if part.index != 0:
        problems, skipped = [], []
    return mine, part_record(part, len(mine), len(plan), digest), problems, skipped


def import_r2n2(config: ImportConfig, progress: Callable[[int], None] | None = None) -> dict:
    """Import ``config.renderings`` + ``config.voxels`` into shards under ``config.out``.

    Models that fail (bad metadata, missing PNGs, binvox of another resolution, ...) are recorded
    in the index's ``failures`` with the reason; the others are imported. Returns the summary
    ``{"done", "failed", "skipped", "problems", "seconds", "out"}``."""
    import time

    from sc3d_data.io.shards import INDEX_NAME, SHARD_PATTERN, add_shard_to_index, write_index as write_index_file, \
        write_shard
    from sc3d_data.formats.splits import assign_splits

    t0 = time.monotonic()
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    existing = list(out.glob("shard-*.h5")) + [p for p in [out / INDEX_NAME] if p.exists()]
    if existing and not config.overwrite:
        raise FileExistsError(f"{out}: already holds shards; use another --out or --overwrite")
    for p in existing:
        p.unlink()
    settings = config.settings()
    models, problems = find_r2n2_models(config.renderings, config.voxels, config.categories)
    splits, split_desc, split_problems = assign_splits(models, spec=config.split, seed=config.seed,
                                                       split_file=config.split_file)
    skipped = list(split_problems)
    plan = []
    for m in models:
        if (m.category, m.model_id) in splits:
            plan.append((m, splits[(m.category, m.model_id)]))
        else:
            skipped.append({"source": str(m.rendering_dir.parent), "reason": "not in any split (--split-file)"})
    plan, part, problems, skipped = _take_part(plan, config.part, problems, skipped)
    failures = [dict(p, category="", model_id="") for p in problems]
    shards, objects = [], []
    K = max(1, int(config.objects_per_shard))

    def write_index(complete: bool) -> None:
        write_index_file(out, complete=complete, settings=settings, split=split_desc, shards=shards,
                         objects=objects, failures=failures, skipped=skipped, warnings=[], extra={"part": part})

    write_index(False)
    chunk = 0
    for start in range(0, len(plan), K):
        records = []
        for m, split in plan[start:start + K]:
            try:
                records.append(load_r2n2_object(m, split, config.image_size, config.background,
                                                 config.voxel_frame, config.front))
            except (ValueError, OSError) as e:
                failures.append({"source": str(m.rendering_dir.parent), "category": m.category,
                                 "model_id": m.model_id, "reason": str(e)})
            if progress is not None:
                progress(1)
        if records:
            name = SHARD_PATTERN.format(chunk)
            write_shard(out / name, records, settings)
            add_shard_to_index(shards, objects, name, chunk, records)
            chunk += 1
            write_index(False)
    write_index(True)
    return {"done": len(objects), "failed": len(failures), "skipped": len(skipped),
            "planned": len(plan), "seconds": time.monotonic() - t0, "out": str(out),
            "failures": failures}
