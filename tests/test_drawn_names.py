"""Names in pictures (``io.drawn_names``): a category or model folder named in CJK (``椅子``,
``ジープ``) was drawn as empty boxes in preview's sheet, check's worst objects and eval's
predictions.png, and ``check`` printed matplotlib's "Glyph ... missing from font(s)" warnings
onto stderr; a 200-character name ran off predictions.png, check's titles were cut at the
picture's edge and did not name the category. Characters the font in use cannot draw are now
written ``\\uXXXX``, long names end in ``...`` within their place, and check names the category."""
from __future__ import annotations

import io
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sc3d_cli.data import main as data_main
from sc3d_cli.train import main as train_main
from tests.conftest import SAMPLE_MESHES, run_cli

LONG = "m" * 200
CHAIR, TABLE, JEEP = "椅子", "テーブル", "ジープ"
CHAIR_U, TABLE_U, JEEP_U = r"\u6905\u5b50", r"\u30c6\u30fc\u30d6\u30eb", r"\u30b8\u30fc\u30d7"
FAST = ["--views", "2", "--no-progress", "--workers", "1"]


@pytest.fixture(scope="module")
def cjk_shards(tmp_path_factory) -> Path:
    """Three sample meshes as ``椅子/ジープ``, ``テーブル/ジープ`` (one model id in two
    categories) and ``椅子/mmm...`` (200 characters), 2 views, voxelized."""
    root = tmp_path_factory.mktemp("cjk")
    for category, model, sample in ((CHAIR, JEEP, "car/jeep_psionic.glb"), (TABLE, JEEP, "table/coffee_table_blendswap_ccby.glb"),
                                    (CHAIR, LONG, "chair/chair2_blendswap.glb")):
        (root / "m" / category).mkdir(parents=True, exist_ok=True)
        shutil.copy(SAMPLE_MESHES / sample, root / "m" / category / f"{model}.glb")
    run_cli(data_main, ["render", "--meshes", root / "m", "--out", root / "d", *FAST, "--voxelize"])
    return root / "d"


def _no_glyph_warnings(recwarn) -> None:
    glyphs = [str(w.message) for w in recwarn if "Glyph" in str(w.message)]
    assert not glyphs, glyphs[:3]


def _font_cmap(font_file) -> set[int]:
    """The code points a font file (path or bytes) maps to glyphs, read with fontTools (a
    reader other than the one sc3d uses)."""
    from fontTools.ttLib import TTFont

    return set(TTFont(io.BytesIO(font_file) if isinstance(font_file, bytes) else font_file).getBestCmap())


def test_drawn_names_escape_what_each_font_lacks_and_keep_escapes_whole():
    """PIL's default font and matplotlib's DejaVu Sans draw different characters: each path
    escapes exactly what its own font lacks, and a cut never splits an escape."""
    from matplotlib.font_manager import FontProperties, findfont
    from PIL import ImageFont

    from sc3d_data.io.drawn_names import mpl_name, pil_name

    text = f"{CHAIR} ü/{JEEP} é\u00a0x"
    pil = ImageFont.load_default()
    for name, cmap in ((pil_name(text, 10_000, pil), _font_cmap(pil.path.getvalue())),
                       (mpl_name(text, 10_000, 7), _font_cmap(findfont(FontProperties())))):
        want = "".join(c if ord(c) in cmap else f"\\u{ord(c):04x}" for c in text)
        assert name == want
    assert pil_name(CHAIR, 10_000, pil) == CHAIR_U
    for width in range(20, 120, 3):
        cut = pil_name(JEEP * 3, width, pil)
        assert pil.getlength(cut) <= width or cut == "..."
        assert re.fullmatch(r"(\\u[0-9a-f]{4})*(\.\.\.)?", cut), cut


def test_preview_labels_of_cjk_and_long_names(cjk_shards, tmp_path, monkeypatch, recwarn):
    """The preview's labels: CJK escaped (PIL's default font has no glyph for them), each line
    no wider than the label, measured with the font it is drawn with."""
    from PIL import ImageDraw

    from sc3d_data.qa.preview import LABEL_WIDTH

    drawn, text = [], ImageDraw.ImageDraw.text

    def record(self, xy, words, *args, **kwargs):
        drawn.append((words, kwargs.get("font") or self.getfont()))
        return text(self, xy, words, *args, **kwargs)

    monkeypatch.setattr(ImageDraw.ImageDraw, "text", record)
    run_cli(data_main, ["preview", cjk_shards, "--out", tmp_path / "sheet.png", "--views", "2"])
    _no_glyph_warnings(recwarn)
    lines = [(line, font) for words, font in drawn for line in words.split("\n")]
    assert {CHAIR_U, TABLE_U, JEEP_U} <= {line for line, _ in lines}, [line for line, _ in lines]
    assert not any(ord(c) > 127 for line, _ in lines for c in line), [line for line, _ in lines]
    assert any(line.startswith("mmm") and line.endswith("...") for line, _ in lines)
    assert all(font.getlength(line) <= LABEL_WIDTH - 8 for line, font in lines)


def _measured(module, monkeypatch) -> dict:
    """Patches ``module.write_figure`` to draw the figure and keep its texts' boxes (pixels),
    then write it as before."""
    seen, write = {}, module.write_figure

    def measure(fig, path, dpi, metadata=None):
        fig.set_dpi(dpi)
        renderer = fig.canvas.get_renderer()
        fig.draw(renderer)
        seen["figure"] = fig.bbox
        seen["axes"] = fig.axes
        seen["titles"] = [(ax.get_title(), ax.title.get_window_extent(renderer)) for ax in fig.axes]
        seen["ylabels"] = [(ax.get_ylabel(), ax.yaxis.label.get_window_extent(renderer)) for ax in fig.axes if ax.get_ylabel()]
        write(fig, path, dpi, metadata)

    monkeypatch.setattr(module, "write_figure", measure)
    return seen


def _inside(box, figure) -> bool:
    return box.x0 >= figure.x0 - 1 and box.x1 <= figure.x1 + 1 and box.y0 >= figure.y0 - 1 and box.y1 <= figure.y1 + 1


def test_check_worst_titles_name_category_and_model_in_the_font(cjk_shards, tmp_path, monkeypatch, recwarn):
    """check_worst.png: ``category/model_id`` escaped, within its column and the picture (200
    m's were cut at the left edge), and the two ``ジープ`` told apart by their category."""
    import sc3d_data.qa.check as check

    seen = _measured(check, monkeypatch)
    run_cli(data_main, ["check", cjk_shards, "--png", tmp_path / "w.png", "--no-progress"])
    _no_glyph_warnings(recwarn)
    titles = seen["titles"]
    names = [t.split("\n")[0] for t, _ in titles[::4]]
    assert f"{CHAIR_U}/{JEEP_U}" in names and any(n.startswith(f"{TABLE_U}/") for n in names), names
    assert any(n.startswith(f"{CHAIR_U}/mmm") and n.endswith("...") for n in names), names
    for (name, box), (_, right) in zip(titles[::4], titles[1::4]):
        assert _inside(box, seen["figure"]) and box.x1 < right.x0, (name, box, right)


def test_check_prints_no_glyph_warnings(cjk_shards, tmp_path):
    """``sc3d-data check --png`` printed three ``UserWarning: Glyph 12472 ... missing from
    font(s) DejaVu Sans`` blocks with sc3d's source paths onto stderr."""
    res = subprocess.run([sys.executable, "-c", "from sc3d_cli.data import main; main()", "check", str(cjk_shards),
                          "--png", str(tmp_path / "w.png"), "--no-progress"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "Glyph" not in res.stderr and "Warning" not in res.stderr, res.stderr


def test_eval_picture_labels_of_cjk_and_long_names(cjk_shards, tmp_path, monkeypatch, recwarn):
    """predictions.png: CJK names escaped, a 200-character model id cut with ``...`` so that its
    label stays within the figure and does not reach another row's label."""
    import sc3d_train.evaluation.evaluate as evaluate

    run = tmp_path / "run"
    run_cli(train_main, ["fit", "--shards", cjk_shards, "--out", run, "--tiny", "--steps", "1", "--batch-size", "2",
                         "--val-every", "0", "--no-progress"])
    seen = _measured(evaluate, monkeypatch)
    run_cli(train_main, ["eval", "--checkpoint", run, "--shards", cjk_shards, "--split", "train"])
    _no_glyph_warnings(recwarn)
    labels = seen["ylabels"]
    assert len(labels) == 3
    texts = [t.split("\n") for t, _ in labels]
    assert [CHAIR_U, JEEP_U] in [t[:2] for t in texts] and [TABLE_U, JEEP_U] in [t[:2] for t in texts], texts
    assert any(t[1].startswith("mmm") and t[1].endswith("...") for t in texts), texts
    boxes = [box for _, box in labels]
    assert all(_inside(box, seen["figure"]) for box in boxes), boxes
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:]), boxes


def test_names_with_dollar_signs_are_names_not_formulas(tmp_path, monkeypatch):
    """A model named ``a$\\frac$b`` (a legitimate file name) made matplotlib parse mathtext:
    ``check --png`` ended in a ParseSyntaxException traceback (eval's picture too), and
    ``$5 and $6`` would have been drawn in math italics. Names are drawn as written."""
    import numpy as np

    import sc3d_data.qa.check as check
    from sc3d_train.evaluation.evaluate import plot_examples

    name = "a$\\frac$b"
    (tmp_path / "m" / "c$x").mkdir(parents=True)
    shutil.copy(SAMPLE_MESHES / "car/jeep_psionic.glb", tmp_path / "m" / "c$x" / f"{name}.glb")
    run_cli(data_main, ["render", "--meshes", tmp_path / "m", "--out", tmp_path / "d", *FAST, "--voxelize"])
    seen = _measured(check, monkeypatch)
    run_cli(data_main, ["check", tmp_path / "d", "--png", tmp_path / "w.png", "--no-progress"])
    assert seen["titles"][0][0].startswith(f"c$x/{name}\n")
    grid = np.zeros((32, 32, 32), bool)
    grid[10:20, 10:20, 10:20] = True
    K = np.array([[70.0, 0, 32], [0, 70, 32], [0, 0, 1]], np.float32)
    example = dict(category="c$x", model_id=name, view=3, image=np.ones((64, 64, 3)), mask_true=np.zeros((64, 64)),
                   mask_pred=np.zeros((64, 64)), voxels_true=grid, voxels_pred=grid * 1.0, K=K, distance=2.0,
                   azimuth_true=0.0, elevation_true=30.0, azimuth_pred=15.0, elevation_pred=30.0, rotation_error=15.0,
                   iou=0.5)
    plot_examples([example], tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 0


@pytest.mark.parametrize("extra", [0, 10])
def test_claims_picture_names_cjk_and_long_categories(tmp_path, monkeypatch, recwarn, extra):
    """claims.png's category names (a study of a user's categories): CJK escaped, not boxes with
    warnings; a 200-character name cut so that no two names overlap and all stay in the picture
    (level with few categories, slanted with many); ``chair (old)`` whole, not cut at `` (``."""
    import sc3d_train.evaluation.claims_report as report

    boxes = {}

    def measure(fig, path, dpi, metadata=None):
        renderer = fig.canvas.get_renderer()
        fig.draw(renderer)
        ticks = fig.axes[0].get_xticklabels()
        boxes.update(texts=[t.get_text() for t in ticks], ticks=[t.get_window_extent(renderer) for t in ticks],
                     figure=fig.bbox)

    monkeypatch.setattr(report, "write_figure", measure)
    cats = [CHAIR, LONG, "chair (old)"] + [f"c{k}" for k in range(extra)]
    figures = {"per_category": {c: {"voxel_iou_0.4": 0.5, "pose_rotation_acc30": 0.5} for c in cats},
               "mean": {"voxel_iou_0.4": 0.5, "pose_rotation_acc30": 0.5}, "overall": {}}
    report.plot_report({name: figures for name in report.RUNS + report.REFERENCES}, tmp_path / "claims.png")
    _no_glyph_warnings(recwarn)
    texts, ticks = boxes["texts"], boxes["ticks"]
    assert CHAIR_U in texts and "chair (old)" in texts, texts
    assert any(t.startswith("mmm") and t.endswith("...") for t in texts), texts
    assert all(_inside(box, boxes["figure"]) for box in ticks), ticks
    if not extra:
        assert not any(a.overlaps(b) for i, a in enumerate(ticks) for b in ticks[i + 1:]), ticks
