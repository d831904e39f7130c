"""Human-readable summary of a shard directory's ``index.json`` (for ``sc3d-data info``)."""
from __future__ import annotations

from pathlib import Path

from sc3d_data.io.names import printable
from sc3d_data.io.shards import held_voxel_resolution, load_index
from sc3d_data.io.shard_reader import verify_shards
from sc3d_data.formats.shapenet import category_label


def integrity_report(shard_dir: Path, full: bool = False) -> list[str]:
    """One line per broken shard (missing, wrong size; with ``full`` also SHA-256 / HDF5
    checksums), empty when all are intact."""
    return verify_shards(shard_dir, full=full)


def _said_once(source: str, reason: str) -> str:
    """``SOURCE: REASON``, or ``REASON`` alone when it already starts with the source (most
    loaders' reasons name their file)."""
    return reason if reason.startswith(f"{source}:") else f"{source}: {reason}"


def voxels_line(index: dict) -> str:
    """What voxel grids the shards of ``index`` hold: those of ``sc3d-data voxelize SHARDS`` (its
    ``voxels`` record, which the render settings do not show), else the render's or import's."""
    record, resolution = index.get("voxels"), held_voxel_resolution(index)
    if record:
        return (f"{resolution}^3, added by `sc3d-data voxelize` ({record.get('failed', 0)} failed; "
                "they replace the voxel settings of the run below)")
    if resolution is not None:
        return f"{resolution}^3, made by the run (settings below)"
    return "none (add them with `sc3d-data voxelize SHARD_DIR`)"


def index_report(shard_dir: Path, max_failures: int = 50) -> str:
    """Counts per category and split (with the part of a ``--part I/N`` run), the voxels the shards
    hold (:func:`voxels_line`), settings, shards, clipped views, failures with reasons,
    skipped files and warnings, as plain text; names from disk in ``io.names.printable`` form
    (no control characters or undecodable bytes reach the terminal)."""
    index = load_index(shard_dir)
    lines = [f"{shard_dir}: sc3d shards (schema {index.get('schema_version')}, sc3d {index.get('sc3d_version')})"
             + ("" if index.get("complete") else "  [INCOMPLETE: rerun the same render command to resume]")]
    counts = index.get("counts", {})
    splits = sorted(counts.get("by_split", {}))
    lines.append(f"\nobjects: {counts.get('total', 0)} in {len(index.get('shards', []))} shards")
    part = index.get("part", {})
    if part.get("count", 1) > 1 and "merged" not in index:  # a --part I/N run (or a SLURM array task's)
        lines.append(f"part {part.get('index')}/{part['count']}: {part.get('assigned', '?')} of "
                     f"{part.get('planned_total', '?')} planned objects; merge the parts into one dataset "
                     "(sc3d-data merge OUT PART_DIR...)")
    header = f"  {'category':<24}" + "".join(f" {printable(s):>7}" for s in splits) + f"{'total':>8}"
    lines.append(header)
    for cat, per in counts.get("by_category", {}).items():
        lines.append(f"  {printable(category_label(cat)):<24}" + "".join(f"{per.get(s, 0):>8}" for s in splits) + f"{sum(per.values()):>8}")
    lines.append(f"  {'all':<24}" + "".join(f"{counts['by_split'][s]:>8}" for s in splits) + f"{counts.get('total', 0):>8}")
    clipped = index.get("clipped", {})
    lines.append(f"\nclipped views (mask touches the border): {clipped.get('views', 0)} in {clipped.get('objects', 0)} objects")
    lines.append(f"\nvoxels: {voxels_line(index)}")
    lines.append("\nsettings:")
    for k, v in index.get("settings", {}).items():
        lines.append(f"  {k}: {printable(v)}")
    if "split" in index:
        lines.append(f"  split rule: {index['split'].get('spec', index['split'].get('method'))}")
    failures = index.get("failures", [])
    lines.append(f"\nfailures: {len(failures)}")
    for f in failures[:max_failures]:
        tries = f" (attempts: {f['attempts']})" if f.get("attempts", 1) > 1 else ""
        lines.append(f"  {_said_once(printable(f.get('source')), printable(f.get('reason')))}{tries}")
    if len(failures) > max_failures:
        lines.append(f"  ... {len(failures) - max_failures} more (see index.json)")
    skipped = index.get("skipped", [])
    if skipped:
        lines.append(f"\nskipped: {len(skipped)}")
        lines.extend(f"  {_said_once(printable(s.get('source')), printable(s.get('reason')))}" for s in skipped[:max_failures])
    warnings = index.get("warnings", [])
    if warnings:
        lines.append(f"\nwarnings: {len(warnings)}")
        lines.extend(f"  {printable(w.get('warning'))}" for w in warnings[:max_failures])
    return "\n".join(lines)
