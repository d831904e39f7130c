"""The training config: the dataclasses are the one source of defaults (the fit options cannot
drift from them), a run's config.yaml reproduces it, and bad config files fail with one line
naming the file and the key."""
from __future__ import annotations

import json
from dataclasses import fields

import pytest
import torch
import yaml

from sc3d_cli.train import main
from tests.conftest import run_cli

TINY = ["--tiny", "--base-channels", "4", "--no-progress"]


def fit_command():
    from sc3d_cli.train_fit import fit

    return fit


def test_fit_options_are_the_dataclass_fields_with_their_defaults():
    """Every field declared for the command line has one option whose default is the
    dataclass's, and every other fit option is one of the few written by hand."""
    from sc3d_train.settings.config import LossWeights, ModelConfig, RunConfig
    from sc3d_train.settings.config_io import cli_fields

    params = {p.name: p for p in fit_command().params}
    declared = {}
    for cls in (RunConfig, ModelConfig):
        declared.update({f.name: f for f in cli_fields(cls)})
        defaults = {f.name: f.default for f in fields(cls)}
        for f in cli_fields(cls):
            assert params[f.name].default == defaults[f.name], f.name
    assert not [f for f in fields(LossWeights) if f.name in params]  # config-file only
    hand_written = set(params) - set(declared)
    assert hand_written == {"config_file", "shards", "out", "semi", "labeled_only", "tiny", "resume"}
    # the options users know keep their names
    for opt in ("--steps", "--batch-size", "--lr", "--lr-schedule", "--semi-lr", "--labeled-fraction",
                "--pretrain-steps", "--voxel-decoder", "--base-channels", "--no-progress", "--amp"):
        assert any(opt in p.opts or opt in p.secondary_opts for p in params.values()), opt


@pytest.mark.parametrize("command, config, function", [
    ("sc3d_cli.train_eval:eval_cmd", "EvalConfig", "sc3d_train.evaluation.evaluate:evaluate"),
    ("sc3d_cli.train_predict:predict", "PredictConfig", "sc3d_train.evaluation.predict:predict"),
    ("sc3d_cli.train_claims:claims", "ClaimsConfig", "sc3d_train.evaluation.claims:run_all")])
def test_eval_predict_claims_options_and_functions_share_the_dataclass_defaults(command, config, function):
    import importlib
    import inspect

    from sc3d_train.settings import command_config
    from sc3d_train.settings.config_io import cli_fields, defaults_of

    def load(target):
        module, name = target.split(":")
        return getattr(importlib.import_module(module), name)

    cls = getattr(command_config, config)
    defaults = defaults_of(cls)
    params = {p.name: p for p in load(command).params}
    signature = inspect.signature(load(function)).parameters
    for f in cli_fields(cls):
        assert params[f.name].default == defaults[f.name], f.name
        if signature[f.name].default is not inspect.Parameter.empty:  # eval's split is positional
            assert signature[f.name].default == defaults[f.name], f.name


def test_one_tiny_preset_and_one_mask_size():
    from sc3d_train.settings.config import MASK_SIZE, ModelConfig
    from sc3d_train.data.dataset import ShardDataset

    tiny = ModelConfig.tiny()
    assert (tiny.base_channels, tiny.shape_dim, tiny.pose_dim) == (8, 32, 8)
    assert ModelConfig().mask_size == MASK_SIZE == 48  # the paper's 48 x 48 masks
    import inspect

    assert inspect.signature(ShardDataset).parameters["mask_size"].default == MASK_SIZE


def test_plain_data_round_trip_and_errors(tmp_path):
    from sc3d_train.settings.config import LossWeights, ModelConfig, RunConfig
    from sc3d_train.settings.config_io import ConfigError, from_plain

    cfg = RunConfig(shards="/s", out="/o", model=ModelConfig.tiny(), loss_weights=LossWeights(proj=0.0))
    plain = cfg.to_dict()
    assert plain["model"]["base_channels"] == 8 and plain["loss_weights"]["proj"] == 0.0
    assert RunConfig.from_dict(plain) == cfg
    # YAML 1.1 reads "2e-4" as a string: a float field takes it
    assert from_plain(RunConfig, {**plain, "lr": "2e-4"}).lr == 2e-4
    with pytest.raises(ConfigError, match=r"unknown ModelConfig keys \['model.depth'\]"):
        RunConfig.from_dict({**plain, "model": {**plain["model"], "depth": 3}})
    with pytest.raises(ConfigError, match=r"steps: expected int, got 'many'"):
        RunConfig.from_dict({**plain, "steps": "many"})
    with pytest.raises(ConfigError, match=r"loss_weights.unlabeled_sc_at_search: expected bool"):
        RunConfig.from_dict({**plain, "loss_weights": {"unlabeled_sc_at_search": 1}})
    with pytest.raises(ConfigError, match=r"missing RunConfig keys \['shards'\]"):
        RunConfig.from_dict({"out": "/o"})
    with pytest.raises(ConfigError, match="mode must be one of"):
        RunConfig.from_dict({**plain, "mode": "self"})


def test_config_yaml_reproduces_the_run(sample_shards, tmp_path):
    """A run made with options and a run made from its config.yaml (another --out) end with
    identical weights; an option given beside --config overrides the file (different weights:
    the negative control); a run folder with the config.json of earlier versions resumes; an
    unknown or ill-typed key in the file is refused with one line."""
    from sc3d_train.loop.checkpoint import load_checkpoint
    from sc3d_train.settings.config import RunConfig

    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    run_cli(main, ["fit", "--shards", sample_shards, "--out", a, "--steps", "2", "--batch-size", "2",
                   *TINY, "--seed", "3", "--lr", "2e-3", "--lr-schedule", "constant"])
    run_cli(main, ["fit", "--config", a / "config.yaml", "--out", b])
    run_cli(main, ["fit", "--config", a / "config.yaml", "--out", c, "--seed", "4"])
    cfg_a, cfg_b, cfg_c = (RunConfig.load(d / "config.yaml") for d in (a, b, c))
    assert (cfg_a.seed, cfg_a.lr, cfg_a.steps) == (3, 2e-3, 2)
    assert (cfg_a.model.base_channels, cfg_a.model.shape_dim) == (4, 32)  # --tiny, then --base-channels
    assert cfg_b.differences(cfg_a, ignore=("out",)) == []
    assert cfg_c.differences(cfg_a, ignore=("out",)) == ["seed: 4 != 3"]
    w = {d: load_checkpoint(d / "checkpoints" / "last.pt")["model"] for d in (a, b, c)}  # weights_only
    assert all(torch.equal(w[a][k], w[b][k]) for k in w[a])
    assert not all(torch.equal(w[a][k], w[c][k]) for k in w[a] if w[a][k].is_floating_point())

    # a run folder of an earlier version holds config.json (the same dict, as JSON): it resumes
    (a / "config.json").write_text(json.dumps(yaml.safe_load((a / "config.yaml").read_text())))
    (a / "config.yaml").unlink()
    r = run_cli(main, ["fit", "--out", a, "--resume", "--steps", "3"])
    assert "done: step 3" in r.output and (a / "config.yaml").is_file()

    bad = tmp_path / "bad.yaml"
    plain = yaml.safe_load((a / "config.yaml").read_text())
    bad.write_text(yaml.safe_dump({**plain, "bogus": 1}))
    r = run_cli(main, ["fit", "--config", bad, "--out", tmp_path / "d"], expect_exit=1)
    line = r.output.strip()
    assert "\n" not in line and str(bad) in line and "'bogus'" in line and "Traceback" not in line
    bad.write_text(yaml.safe_dump({**plain, "model": {**plain["model"], "base_channels": "wide"}}))
    r = run_cli(main, ["fit", "--config", bad, "--out", tmp_path / "d"], expect_exit=1)
    assert str(bad) in r.output and "model.base_channels: expected int, got 'wide'" in r.output
    bad.write_text("steps: [1,\n")
    r = run_cli(main, ["fit", "--config", bad, "--out", tmp_path / "d"], expect_exit=1)
    assert str(bad) in r.output and "not valid YAML" in r.output
    assert not (tmp_path / "d").exists()


def test_docs_tables_match_the_dataclasses():
    from pathlib import Path

    from sc3d_train.settings.config import LossWeights, ModelConfig, RunConfig
    from sc3d_train.settings.config_io import markdown_table

    doc = (Path(__file__).resolve().parents[1] / "docs" / "config.md").read_text()
    for cls in (RunConfig, ModelConfig, LossWeights):
        assert markdown_table(cls) in doc, f"docs/config.md: the {cls.__name__} table is out of date"
