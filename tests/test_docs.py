"""Every shell command in README.md and docs/*.md is checked against the code.

The convention (README.md, "Documentation", points here):

* Shell blocks are fenced ```bash, ```sh or ```console (in ```console only lines starting with
  ``$ `` are commands). Other fences (```text, ```python ...) are not checked.
* **Parse check, every block.** Each ``sc3d-data ...`` / ``sc3d-train ...`` invocation (also after
  ``torchrun ... $(which sc3d-train)``, ``nice`` or ``VAR=value``) must parse against the real
  click commands named by pyproject.toml's ``[project.scripts]``: the subcommand exists, every
  option exists and gets its value, choice values are allowed, positional arguments fit and
  required options are given. Nothing is executed and paths need not exist, so blocks about data
  that is not shipped (ShapeNet, 3D-R2N2's release, a cluster) are checked this way only.
  ``python benchmarks/NAME.py`` and ``bash scripts/NAME.sh``: the file exists and every ``--option``
  is one the script's argparse declares.
* **Run check, blocks marked ``<!-- doc-run -->``** (the line just before the fence): run with
  ``bash -euo pipefail``, the blocks of one page in order, in a fresh temporary folder per page
  that holds a link ``assets`` to the repository's ``assets/`` (so the bundled sample meshes and
  images are where the docs say, "from the repository root"), with ``sc3d-data`` / ``sc3d-train``
  on PATH running this checkout. Before running, training lengths are shrunk so a page runs in
  seconds: ``--steps N``, ``--pretrain-steps N`` and ``--checkpoint-every N`` become
  ``max(1, N // 100)`` (so 300 then 600 with ``--resume`` become 3 then 6), ``--batch-size N``
  becomes ``min(N, 4)``. Everything else runs as written: a doc-run block may only use the
  bundled sample meshes and what earlier doc-run blocks of its page wrote. The files the page
  promises are then checked (``PROMISED`` below).
* **Links.** Relative links ``[text](path#anchor)`` must name existing files (and headings, by
  GitHub's anchor rule), and repository paths in inline code or commands (``benchmarks/x.py``,
  ``tests/test_x.py::test_name`` ...) must exist, and so must dotted names of the packages in
  inline code (``sc3d_data.geometry.normalize.apply_transform``). ``PENDING_PAGES`` are pages written on other
  branches of the same change: a link to one is checked once the page exists.
"""
from __future__ import annotations

import re
import subprocess

import pytest

from doc_check import (PAGES, PROMISED, REPO, RUN_MARKER, all_blocks, check_text, cli_groups, commands,
                       link_problems, prose, python_name_problems, repo_path_problems,
                       rewrite_for_run, shell_blocks, slug)

#: subcommands the doc-run blocks must exercise together
MUST_RUN = {"render", "voxelize", "info", "check", "preview", "fit", "eval", "predict"}


# --------------------------------------------------------------------------- tests: the checker

@pytest.fixture(scope="module")
def groups():
    return cli_groups()


def test_checker_accepts_a_correct_command(groups):
    assert check_text("sc3d-data render --out shards/ --voxelize --views 4  # comment\n", groups) == []
    assert check_text("torchrun --nproc_per_node 2 $(which sc3d-train) fit --out r/ \\\n  --steps 5\n",
                      groups) == []


@pytest.mark.parametrize("text, expected", [
    ("sc3d-data render --out shards/ --no-such-option\n", "No such option"),
    ("sc3d-train fit --out run/ --stepz 3\n", "No such option"),
    ("sc3d-data rendr --out shards/\n", "no command 'rendr'"),
    ("sc3d-data render --out shards/ --normalize cube\n", "not one of"),
    ("sc3d-train eval --shards shards/\n", "missing --checkpoint"),
    ("sc3d-data info a/ b/\n", "unexpected extra arguments"),
    ("sc3d-data render --out\n", "requires an argument"),
    ("x=1; cd /tmp && sc3d-train predict --checkpoint c.pt --treshold 0.4 a.png\n", "No such option"),
    ("python benchmarks/render.py --meshes m/ --no-such-flag\n", "has no option --no-such-flag"),
    ("python benchmarks/no_such_script.py\n", "does not exist"),
])
def test_checker_rejects_a_wrong_command(groups, text, expected):
    problems = check_text(text, groups)
    assert any(expected in p for p in problems), problems


def test_link_and_path_checks_catch_missing_targets(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# The `real` heading: yes\n[a](missing.md) [b](#nope) [c](#the-real-heading-yes)\n"
                    "![d](page.md#the-real-heading-yes) [e](https://example.org/x#y)\n"
                    "```bash\n[f](in-code.md)\n```\n")
    assert link_problems(page) == [f"{page}: link to missing missing.md", f"{page}: no heading #nope in {page}"]
    assert repo_path_problems("see `benchmarks/no_such.py` and `tests/test_docs.py::test_nope`", "x") == [
        "x: benchmarks/no_such.py does not exist", "x: tests/test_docs.py has no test_nope"]
    assert repo_path_problems("`run/config.json`, `tests/test_docs.py::test_rewrite_shrinks_training`", "x") == []
    assert python_name_problems("`sc3d_data.geometry.normalize.apply_transform`, `sc3d_data.no_such.f`, "
                                "`sc3d_data.geometry.normalize.no_such_function`", "x") == [
        "x: sc3d_data.geometry.normalize.no_such_function does not exist", "x: sc3d_data.no_such.f does not exist"]
    assert slug("3D-R2N2's release: `import-r2n2`") == "3d-r2n2s-release-import-r2n2"



def test_rewrite_shrinks_training():
    assert rewrite_for_run("fit --steps 300 --batch-size 8 --pretrain-steps=50 --checkpoint-every 100") == \
        "fit --steps 3 --batch-size 4 --pretrain-steps=1 --checkpoint-every 1"
    assert rewrite_for_run("fit --steps 600 --resume --batch-size 2") == "fit --steps 6 --resume --batch-size 2"


# --------------------------------------------------------------------------- tests: the docs

@pytest.mark.parametrize("block", all_blocks(), ids=lambda b: b.where())
def test_every_command_parses(block, groups):
    problems = check_text(block.text, groups)
    assert problems == [], f"{block.where()}: " + "\n".join(problems)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_links_and_paths_exist(page):
    where = str(page.relative_to(REPO))
    inline = " ".join(re.findall(r"`([^`\n]+)`", prose(page)))
    blocks = " ".join(b.text for b in shell_blocks(page))
    problems = (link_problems(page) + repo_path_problems(inline + " " + blocks, where)
                + python_name_problems(inline, where))
    assert problems == [], "\n".join(problems)


def test_doc_run_blocks_cover_the_main_commands(groups):
    ran = set()
    for block in all_blocks():
        if block.run:
            for tokens in commands(block.text):
                for i, tok in enumerate(tokens):
                    if tok in groups and i + 1 < len(tokens):
                        ran.add(tokens[i + 1])
    assert MUST_RUN <= ran, MUST_RUN - ran
    assert set(PROMISED) <= {str(b.page.relative_to(REPO)) for b in all_blocks() if b.run}


@pytest.mark.parametrize("page", sorted(PROMISED), ids=str)
def test_doc_run_blocks_run(page, doc_runs):
    proc, work, log, script = doc_runs[page]
    assert "### running" in script, f"{page} has no {RUN_MARKER} block"
    try:
        rc = proc.wait(timeout=600)
    except subprocess.TimeoutExpired:
        proc.kill()
        rc = proc.wait()
    output = log.read_text()
    assert rc == 0, f"{page}: doc-run failed ({rc}):\n{script}\n{output[-4000:]}"
    missing = [f for f in PROMISED[page] if not (work / f).exists()]
    assert missing == [], f"{page}: its doc-run blocks did not write {missing}"
