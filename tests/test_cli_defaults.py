"""The data commands' click options agree with the settings dataclasses they fill.

``RenderConfig`` (``sc3d_data.pipeline.jobs.render_job``) and ``ImportConfig``
(``sc3d_data.pipeline.jobs.r2n2_job``) are the one source of defaults for ``sc3d-data render`` and
``sc3d-data import-r2n2``; the click options repeat them for ``--help``. This test fails when
one drifts from the other. (``sc3d-train``'s options are generated from its dataclasses:
tests/test_config.py.) Options whose text is parsed by the command (``--elevations 30``,
``--background 255,255,255``) are compared after the command's own parsing.
"""
from __future__ import annotations

import dataclasses

import click
import pytest


def option_default_drift(command: click.Command, config_cls, parse: dict, required: list[str] = ()) -> list[str]:
    """``NAME: option default X != dataclass default Y`` for every option of ``command`` that
    fills a field of ``config_cls``. The defaults are the values click hands the command when
    only the ``required`` arguments are given (types and callbacks applied); ``parse`` maps a
    field to the function the command applies to such a value before building the config."""
    fields = {f.name: f for f in dataclasses.fields(config_cls)}
    given = command.make_context("check", [str(a) for a in required]).params
    drift = []
    for param in command.params:
        if not isinstance(param, click.Option) or param.name not in fields:
            continue
        f = fields[param.name]
        if f.default is dataclasses.MISSING:
            continue
        value = given[param.name]
        value = parse[param.name](value) if param.name in parse else value
        if value != f.default:
            drift.append(f"{param.name}: option default {value!r} != dataclass default {f.default!r}")
    return drift


def test_checker_catches_a_drifted_default():
    @dataclasses.dataclass
    class Settings:
        size: int = 64
        colour: tuple = (1, 2)

    @click.command()
    @click.option("--size", default=32)
    @click.option("--colour", default="1,2")
    def cmd(size, colour):
        pass

    drift = option_default_drift(cmd, Settings, {"colour": lambda s: tuple(int(c) for c in s.split(","))})
    assert drift == ["size: option default 32 != dataclass default 64"]


def render_case(tmp):
    from sc3d_cli.data_render import _floats, _rgb, _split_files, render
    from sc3d_data.pipeline.jobs.render_job import RenderConfig

    return render, RenderConfig, {"elevations": _floats, "background": _rgb, "split_file": _split_files}, \
        ["--out", tmp / "out"]


def import_case(tmp):
    from sc3d_cli.data_import_r2n2 import import_r2n2
    from sc3d_data.pipeline.jobs.r2n2_job import ImportConfig

    def rgb(text):
        return tuple(int(c) for c in text.split(","))

    return import_r2n2, ImportConfig, {"background": rgb, "split_file": lambda v: list(v) or None}, \
        ["--renderings", tmp, "--voxels", tmp, "--out", tmp / "out"]


@pytest.mark.parametrize("case", [render_case, import_case], ids=["render", "import-r2n2"])
def test_data_command_defaults_equal_their_dataclass(case, tmp_path, monkeypatch):
    for var in ("SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "SLURM_ARRAY_TASK_MIN"):
        monkeypatch.delenv(var, raising=False)  # --part defaults to the array task inside one
    command, config_cls, parse, required = case(tmp_path)
    matched = [p for p in command.params if isinstance(p, click.Option)
               and p.name in {f.name for f in dataclasses.fields(config_cls)}]
    assert len(matched) >= 10, "the command's options no longer fill the dataclass by name"
    assert option_default_drift(command, config_cls, parse, required) == []
