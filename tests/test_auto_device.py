"""What ``--device auto`` picks (``sc3d_train.loop.runtime.auto_device``): CUDA when torch sees a
GPU, unless ``SC3D_AUTO_DEVICE`` names the device. The test suite sets ``cpu`` (``conftest.py``)
so that its CPU tests, whose bounds and exact comparisons are the CPU's, train on the CPU on a
GPU machine as well; ``tests/test_gpu.py`` checks that there for real."""
from __future__ import annotations

import pytest
import torch

from sc3d_cli.train import main as train_main
from sc3d_train.loop import runtime
from tests.conftest import run_cli
from tests.test_train import TINY


def gpu_machine(monkeypatch):
    """torch as it answers on a machine with a GPU (only the question ``auto`` asks)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)


def test_auto_is_cuda_on_a_gpu_machine_unless_the_environment_says_cpu(monkeypatch):
    gpu_machine(monkeypatch)
    monkeypatch.delenv(runtime.AUTO_DEVICE_ENV, raising=False)
    assert runtime.auto_device() == "cuda"
    monkeypatch.setenv(runtime.AUTO_DEVICE_ENV, "")
    assert runtime.auto_device() == "cuda"  # empty = unset
    monkeypatch.setenv(runtime.AUTO_DEVICE_ENV, "cpu")
    assert runtime.auto_device() == "cpu"
    assert runtime.resolve_device("auto") == torch.device("cpu")


def test_auto_is_the_cpu_without_a_gpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.delenv(runtime.AUTO_DEVICE_ENV, raising=False)
    assert runtime.resolve_device("auto") == torch.device("cpu")


@pytest.mark.parametrize("value, message", [
    ("gpu", "SC3D_AUTO_DEVICE='gpu': --device auto can mean cpu or cuda"),
    ("cuda", "SC3D_AUTO_DEVICE=cuda: CUDA is not available here"),
])
def test_a_bad_auto_device_is_one_line_naming_the_variable(sample_shards, tmp_path, monkeypatch, value, message):
    if value == "cuda" and torch.cuda.is_available():
        pytest.skip("this machine has CUDA: SC3D_AUTO_DEVICE=cuda is valid here")
    monkeypatch.setenv(runtime.AUTO_DEVICE_ENV, value)
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", 1, *TINY],
                  expect_exit=1)
    last = res.output.strip().splitlines()[-1]
    assert message in last and "Traceback" not in res.output, res.output


def test_fit_says_where_it_trained(sample_shards, tmp_path):
    """The suite's own setting: ``--device auto`` trains on the CPU and ``fit`` says so."""
    res = run_cli(train_main, ["fit", "--shards", sample_shards, "--out", tmp_path / "run", "--steps", 1, *TINY,
                               "--val-every", 0, "--no-progress"])
    assert "samples/s on cpu;" in res.output, res.output
