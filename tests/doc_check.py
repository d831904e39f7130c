"""Reading the shell blocks, links and paths of README.md and docs/*.md, and checking commands
against the real command line without running them (used by tests/test_docs.py, whose docstring
states the convention)."""
from __future__ import annotations

import re
import shlex
import sys
import tomllib
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path

import click

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
SHELL_FENCES = {"bash", "sh", "shell", "console"}
RUN_MARKER = "<!-- doc-run -->"
CLI_NAMES = ("sc3d-data", "sc3d-train")
#: pages linked from the docs that other branches of the same change add
PENDING_PAGES: set = set()


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
        entry = getattr(import_module(module), attr)  # a click group, or a function running one (its .group)
        groups[name] = entry if isinstance(entry, click.Command) else entry.group
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


def _name(path: Path) -> str:
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


def link_problems(page: Path) -> list[str]:
    """Relative links of a page (outside code) to missing files or headings."""
    problems = []
    for target in re.findall(r"\]\(([^)\s]+)\)", prose(page)):
        if re.match(r"^[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            if dest not in PENDING_PAGES:
                problems.append(f"{_name(page)}: link to missing {target}")
            continue
        if anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            problems.append(f"{_name(page)}: no heading #{anchor} in {_name(dest)}")
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




#: files each page's doc-run blocks must leave in their folder (what the text says they write)
PROMISED = {
    "README.md": ["shards/index.json", "shards/check_worst.png", "sheet.png",
                  "vox/chair/silla_blanca_blendswap.binvox", "run/checkpoints/last.pt",
                  "run/eval_test/metrics.json", "run/predictions/chair.obj"],
    "docs/data.md": ["shards/index.json", "check.json", "sheet.png",
                     "vox/airplane/c182_fgai.binvox"],
    # step_000006.pt: `--steps 600 --resume` (shrunk to 6) continued the 3-step run
    "docs/training.md": ["run/config.yaml", "run/checkpoints/step_000003.pt",
                         "run/checkpoints/step_000006.pt", "run/metrics.csv",
                         "run/eval_test/metrics.json", "run/eval_test/predictions.png",
                         "run/predictions/chair.binvox", "run/predictions/chair.npz",
                         "run/predictions/chair.obj", "run/predictions/chair.json",
                         "run/predictions/chair.png", "run_semi/labeled_objects.txt"],
}

def start_doc_runs(root: Path) -> dict[str, tuple]:
    """Start every ``PROMISED`` page's doc-run script at once, each in its own folder ``root/pageI``
    (see the module docstring of ``test_docs``), so the pages share the machine's cores, when this
    process creates ``root`` (another process of the session may have: then its runs are
    these; ``shared_runs``); returns ``{page: (SharedRun, folder, log file, script)}``: the tests
    wait for their page."""
    import os

    from shared_runs import SharedRun, claim, start_shared

    starts = claim(root)
    if starts:
        cli_shims(root / "bin")
    env = dict(os.environ, PATH=f"{root / 'bin'}{os.pathsep}{os.environ['PATH']}",
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    runs = {}
    for i, page in enumerate(sorted(PROMISED)):
        work, log, rc, script = root / f"page{i}", root / f"page{i}.log", root / f"page{i}.rc", page_script(page)
        if starts:
            work.mkdir()
            (work / "assets").symlink_to(REPO / "assets")
            run = start_shared(rc, ["bash", "-c", script], log, cwd=work, env=env, text=True)
        else:
            run = SharedRun(rc, None)
        runs[page] = (run, work, log, script)
    return runs


def rewrite_for_run(text: str) -> str:
    """Shrink training lengths of a doc-run block (see the module docstring)."""
    text = re.sub(r"(--(?:steps|pretrain-steps|checkpoint-every)[ =])(\d+)",
                  lambda m: f"{m.group(1)}{max(1, int(m.group(2)) // 100)}", text)
    return re.sub(r"(--batch-size[ =])(\d+)", lambda m: f"{m.group(1)}{min(int(m.group(2)), 4)}", text)



def cli_shims(bin_dir: Path) -> None:
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


def python_name_problems(text: str, where: str) -> list[str]:
    """Dotted names of this repository's packages (``sc3d_data.geometry.normalize.apply_transform``) that
    do not import: the longest importable module prefix, then attributes."""
    problems = []
    for name in sorted(set(re.findall(r"\b(?:sc3d_data|sc3d_train)(?:\.\w+)+", text))):
        parts = name.split(".")
        for cut in range(len(parts), 0, -1):
            try:
                obj = import_module(".".join(parts[:cut]))
                break
            except ImportError:
                continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                problems.append(f"{where}: {name} does not exist")
                break
            obj = getattr(obj, attr)
    return problems
