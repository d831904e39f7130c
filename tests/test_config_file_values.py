"""``fit --config FILE`` with values that are numbers of the wrong size or kind where the config's
own checks do not reach: refused in one line naming the file and the key (docs/config.md), never a
traceback. No shards are read: the file is refused before."""
from __future__ import annotations

from sc3d_cli.train import main
from tests.conftest import run_cli


def fit_with(tmp_path, text: str, *options):
    """``fit --config`` of a file holding ``text``; returns (file, output). Expects exit 1."""
    config = tmp_path / "bad.yaml"
    config.write_text(text)
    shards = tmp_path / "shards"
    shards.mkdir(exist_ok=True)
    result = run_cli(main, ["fit", "--config", config, "--shards", shards, "--out", tmp_path / "run",
                            "--tiny", "--no-progress", *options], expect_exit=1)
    return config, result.output


def test_an_integer_too_large_for_a_float_field_is_refused_naming_the_key(tmp_path):
    # lr: 1 followed by 400 zeros is an int to YAML; float() of it raised OverflowError (a traceback)
    for key, text in (("lr", "lr: 1" + "0" * 400 + "\n"),
                      ("loss_weights.w3d", "loss_weights: {w3d: 1" + "0" * 400 + "}\n")):
        config, output = fit_with(tmp_path, text)
        assert "Traceback" not in output and len(output.strip().splitlines()) == 1, output
        assert f"{config}: {key}:" in output and "too large" in output, output


def test_an_integer_yaml_cannot_read_is_refused_naming_the_file(tmp_path):
    # over Python's 4300-digit limit the YAML reader raised a bare ValueError: no file named
    config, output = fit_with(tmp_path, "steps: 1" + "0" * 5000 + "\n")
    assert "Traceback" not in output and len(output.strip().splitlines()) == 1, output
    assert str(config) in output, output


def test_a_steps_of_the_wrong_type_beside_pretrain_steps_is_no_traceback(tmp_path):
    # defaulted_pretraining computed file_steps // 2 on the file's "100" (TypeError) with --steps given
    for steps in ('"100"', "[100]", "100.5"):
        config, output = fit_with(tmp_path, f"mode: semi\nsteps: {steps}\npretrain_steps: 50\n", "--steps", "10")
        assert "Traceback" not in output and len(output.strip().splitlines()) == 1, output
        assert str(config) in output and "pretrain_steps" in output, output


def test_a_network_no_memory_holds_is_refused_in_one_line(tmp_path, sample_shards):
    # model.shape_dim of 1e11 made torch.empty fail inside nn.Linear: a RuntimeError traceback
    # (given as an option: fit_with's --tiny replaces a file's shape_dim; the option wins over both)
    config, output = fit_with(tmp_path, "val_every: 0\n", "--shards", sample_shards, "--shape-dim",
                              "100000000000", "--steps", "1", "--batch-size", "4")
    assert "Traceback" not in output and "weights alone need" in output and "shape_dim 100000000000" in output, output
