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
  ``tests/test_x.py::test_name`` ...) must exist. ``PENDING_PAGES`` are pages written on other
  branches of the same change: a link to one is checked once the page exists.
"""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path

import click
import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
SHELL_FENCES = {"bash", "sh", "shell", "console"}
RUN_MARKER = "<!-- doc-run -->"
CLI_NAMES = ("sc3d-data", "sc3d-train")
#: pages linked from the docs that other branches of the same change add
PENDING_PAGES = {REPO / "docs" / "ARCHITECTURE.md", REPO / "docs" / "scale.md"}
#: files each page's doc-run blocks must leave in their folder (what the text says they write)
PROMISED = {
    "README.md": ["shards/index.json", "shards/check_worst.png", "sheet.png",
                  "vox/chair/silla_blanca_blendswap.binvox", "run/checkpoints/last.pt",
                  "run/eval_test/metrics.json", "run/predictions/chair.obj"],
    "docs/data.md": ["shards/index.json", "check.json", "sheet.png",
                     "vox/airplane/c182_fgai.binvox"],
    # step_000006.pt: `--steps 600 --resume` (shrunk to 6) continued the 3-step run
    "docs/training.md": ["run/config.json", "run/checkpoints/step_000003.pt",
                         "run/checkpoints/step_000006.pt", "run/metrics.csv",
                         "run/eval_test/metrics.json", "run/eval_test/predictions.png",
                         "run/predictions/chair.binvox", "run/predictions/chair.npz",
                         "run/predictions/chair.obj", "run/predictions/chair.json",
                         "run/predictions/chair.png", "run_semi/labeled_objects.txt"],
}
#: subcommands the doc-run blocks must exercise together
MUST_RUN = {"render", "voxelize", "info", "check", "preview", "fit", "eval", "predict"}


@dataclass(frozen=True)
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    text: str
    run: bool

    def where(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"


def shell_blocks(page: Path) -> list[Block]:
    """The shell blocks of a markdown page, with their doc-run marker."""
    lines = page.read_text(encoding="utf-8").splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = re.match(r"^```(\w*)\s*$", lines[i])
        if not m:
            i += 1
            continue
        start, lang = i, m.group(1)
        j = i + 1
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        body = lines[start + 1:j]
        if lang in SHELL_FENCES:
            if lang == "console":
                body = [ln[2:] for ln in body if ln.startswith("$ ")]
            marked = start > 0 and lines[start - 1].strip() == RUN_MARKER
            blocks.append(Block(page, start + 1, "\n".join(body) + "\n", marked))
        i = j + 1
    return blocks


def all_blocks() -> list[Block]:
    return [b for page in PAGES for b in shell_blocks(page)]


# --------------------------------------------------------------------------- commands in a block

_OPERATORS = {"&&", "||", ";", "|", "&", "(", ")", ";;"}
_REDIRECTS = {">", ">>", "<", "2>", "&>", ">&"}


def commands(text: str) -> list[list[str]]:
    """Simple commands of a shell snippet as token lists (comments dropped, continuation lines
    joined, ``$(which X)`` read as ``X``, redirections removed)."""
    text = text.replace("\\\n", " ")
    text = re.sub(r"\$\(which\s+([\w.-]+)\)", r"\1", text)
    out: list[list[str]] = []
    for line in text.splitlines():
        lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|()<>")
        lexer.whitespace_split = True
        cur: list[str] = []
        tokens = list(lexer)
        k = 0
        while k < len(tokens):
            tok = tokens[k]
            if tok in _OPERATORS:
                if cur:
                    out.append(cur)
                cur = []
            elif tok in _REDIRECTS:
                k += 1  # skip the file name
            else:
                cur.append(tok)
            k += 1
        if cur:
            out.append(cur)
    return out


def cli_groups() -> dict[str, click.Group]:
    """The console scripts of pyproject.toml, imported from this checkout."""
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    groups = {}
    for name in CLI_NAMES:
        module, attr = scripts[name].split(":")
        groups[name] = getattr(import_module(module), attr)
    return groups


def check_cli(group: click.Group, name: str, args: list[str]) -> list[str]:
    """Problems of ``name args`` against the click group, found without running it."""
    if not args or args[0] in ("--help", "--version"):
        return []
    ctx = click.Context(group, info_name=name)
    sub, rest = args[0], args[1:]
    cmd = group.get_command(ctx, sub)
    if cmd is None:
        return [f"`{name}` has no command {sub!r}"]
    if "--help" in rest:
        return []
    sub_ctx = click.Context(cmd, info_name=sub, parent=ctx)
    try:
        values, extra, _ = cmd.make_parser(sub_ctx).parse_args(list(rest))
    except click.UsageError as e:
        return [f"`{name} {sub}`: {e.format_message()}"]
    problems = []
    if extra:
        problems.append(f"`{name} {sub}`: unexpected extra arguments {extra}")
    for p in cmd.params:
        given = values.get(p.name)
        if p.required and given is None:
            problems.append(f"`{name} {sub}`: missing {p.opts[0] if isinstance(p, click.Option) else p.human_readable_name}")
        if given is not None and isinstance(p.type, click.Choice):
            for v in given if isinstance(given, (list, tuple)) else [given]:
                choices = [str(c) for c in p.type.choices]
                ok = v in choices if p.type.case_sensitive else v.lower() in [c.lower() for c in choices]
                if not ok:
                    problems.append(f"`{name} {sub}`: {p.opts[0]} {v!r} is not one of {choices}")
    return problems


def argparse_options(script: Path) -> set[str]:
    """The ``--options`` a script declares with argparse's ``add_argument``."""
    return set(re.findall(r"add_argument\(\s*[\"'](--[\w-]+)", script.read_text(encoding="utf-8")))


def check_command(tokens: list[str], groups: dict[str, click.Group]) -> list[str]:
    """Problems of one simple command; commands this checker does not know are accepted."""
    for i, tok in enumerate(tokens):
        if tok in groups:
            return check_cli(groups[tok], tok, tokens[i + 1:])
    words = [t for t in tokens if not re.match(r"^[A-Z_][A-Z0-9_]*=", t)]
    if len(words) >= 2 and words[0] in ("python", "python3", "bash") and words[1].endswith((".py", ".sh")):
        script = REPO / words[1]
        if not script.is_file():
            return [f"{words[1]} does not exist"]
        if script.suffix == ".py":
            known = argparse_options(script)
            unknown = [a.split("=")[0] for a in words[2:] if a.startswith("--") and a.split("=")[0] not in known]
            if unknown:
                return [f"{words[1]} has no option {', '.join(unknown)}"]
    return []


def check_text(text: str, groups: dict[str, click.Group]) -> list[str]:
    problems = []
    for tokens in commands(text):
        problems += check_command(tokens, groups)
    return problems


# --------------------------------------------------------------------------- links and paths

def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    found, fenced = set(), False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and (m := re.match(r"^#{1,6}\s+(.*)$", line)):
            found.add(slug(m.group(1)))
    return found


def prose(page: Path) -> str:
    """The page without its fenced blocks."""
    return re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)


def link_problems(page: Path) -> list[str]:
    problems = []
    for target in re.findall(r"\]\(([^)\s]+)\)", prose(page)):
        if re.match(r"^[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            if dest not in PENDING_PAGES:
                problems.append(f"{page.relative_to(REPO)}: link to missing {target}")
            continue
        if anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            problems.append(f"{page.relative_to(REPO)}: no heading #{anchor} in {dest.relative_to(REPO)}")
    return problems


_TOP = {p.name for p in REPO.iterdir() if p.is_dir() and not p.name.startswith(".")}


def repo_path_problems(text: str, where: str) -> list[str]:
    """Repository paths (first folder one of the repository's) that do not exist; a
    ``file.py::test_name`` must name a test defined in that file."""
    problems = []
    for word in re.findall(r"[\w.*/-]+/[\w.*/:-]+", text):
        path, _, test = word.partition("::")
        path = path.rstrip("/.:")
        if path.split("/")[0] not in _TOP or "*" in path:
            continue
        full = REPO / path
        if not full.exists():
            problems.append(f"{where}: {path} does not exist")
        elif test and f"def {test}(" not in full.read_text(encoding="utf-8"):
            problems.append(f"{where}: {path} has no {test}")
    return problems


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
    page = REPO / "docs" / "_probe_for_test_docs.md"
    assert not page.exists()
    assert repo_path_problems("see `benchmarks/no_such.py` and `tests/test_docs.py::test_nope`", "x") == [
        "x: benchmarks/no_such.py does not exist", "x: tests/test_docs.py has no test_nope"]
    assert repo_path_problems("`run/config.json`, `tests/test_docs.py::test_rewrite_shrinks_training`", "x") == []
    assert slug("3D-R2N2's release: `import-r2n2`") == "3d-r2n2s-release-import-r2n2"


def rewrite_for_run(text: str) -> str:
    """Shrink training lengths of a doc-run block (see the module docstring)."""
    text = re.sub(r"(--(?:steps|pretrain-steps|checkpoint-every)[ =])(\d+)",
                  lambda m: f"{m.group(1)}{max(1, int(m.group(2)) // 100)}", text)
    return re.sub(r"(--batch-size[ =])(\d+)", lambda m: f"{m.group(1)}{min(int(m.group(2)), 4)}", text)


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
    problems = link_problems(page) + repo_path_problems(inline + " " + blocks, where)
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
    assert {str(Path(p)) for p in PROMISED} <= {
        str(b.page.relative_to(REPO)) for b in all_blocks() if b.run}


def _cli_shims(bin_dir: Path) -> None:
    """``sc3d-data`` / ``sc3d-train`` executables that run this checkout's console scripts with
    this interpreter (whatever an installed copy on PATH would run); guarded like pip's scripts,
    because the render workers are spawned and import the main script again."""
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    bin_dir.mkdir()
    for name in CLI_NAMES:
        module, attr = scripts[name].split(":")
        shim = bin_dir / name
        shim.write_text(f"#!{sys.executable}\nimport sys\nsys.path.insert(0, {str(REPO)!r})\n"
                        f"from {module} import {attr}\nif __name__ == '__main__':\n    sys.exit({attr}())\n")
        shim.chmod(0o755)


def page_script(page: str) -> str:
    """The doc-run blocks of a page as one bash script, shrunk for the run; each block announces
    itself on stderr, so a failure names its block."""
    parts = ["set -euo pipefail"]
    for block in shell_blocks(REPO / page):
        if block.run:
            parts += [f"echo '### running {block.where()}' >&2", rewrite_for_run(block.text)]
    return "\n".join(parts) + "\n"


@pytest.fixture(scope="module")
def doc_runs(tmp_path_factory):
    """Start every page's doc-run script at once (each in its own folder, see the module
    docstring), so the pages share the machine's cores; the tests wait for their page."""
    root = tmp_path_factory.mktemp("doc_run")
    _cli_shims(root / "bin")
    env = dict(os.environ, PATH=f"{root / 'bin'}{os.pathsep}{os.environ['PATH']}",
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    runs = {}
    for i, page in enumerate(sorted(PROMISED)):
        work = root / f"page{i}"
        work.mkdir()
        (work / "assets").symlink_to(REPO / "assets")
        script = page_script(page)
        log = (root / f"page{i}.log").open("w")
        proc = subprocess.Popen(["bash", "-c", script], cwd=work, env=env, stdout=log,
                                stderr=subprocess.STDOUT, text=True)
        runs[page] = (proc, work, root / f"page{i}.log", script)
    yield runs
    for proc, *_ in runs.values():
        if proc.poll() is None:
            proc.kill()
            proc.wait()


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
