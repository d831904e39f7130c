"""Loader worker faults (attack on ``fit --workers``, 2026-12-07): a /dev/shm with room for the
batch ring but not for the rest the workers need, and a worker killed from outside (the kernel's
out-of-memory killer, ``kill -9``), each with the real loader and command."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from conftest import one_error, run_cli

TINY_FIT = ["--tiny", "--batch-size", "4", "--val-every", "0", "--no-progress", "--device", "cpu", "--log-every", "1"]


def _private_shm_works() -> bool:
    probe = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=4m tmpfs /dev/shm"],
                           capture_output=True)
    return probe.returncode == 0


@pytest.mark.parametrize("pages_over", [0, 1], ids=["ring-positions", "worker-queues"])
def test_a_dev_shm_that_holds_the_ring_but_not_the_rest_is_one_line(sample_shards, pages_over):
    """/dev/shm with room for the ring's batches and ``pages_over`` 4 KiB pages more: the page of
    the ring's positions (0) or the workers' queue semaphores (1) do not fit. The first was a
    RuntimeError traceback (the positions were mapped outside the ring's ``try``), the second a
    bare ``No space left on device`` that reads like a full disk; both must be the ring's one
    OSError naming /dev/shm and --workers. Own mount namespace (root), skipped elsewhere."""
    from sc3d_train.data.dataset import ShardDataset
    from sc3d_train.data.loader import _RingBatches, ring_slots

    if not _private_shm_works():
        pytest.skip("needs unshare -m and mount (root in a namespace-capable container)")
    ring = _RingBatches(ShardDataset(sample_shards, "train")).slot_bytes(4) * ring_slots(2)
    fill = 1024 - (ring + 4095) // 4096 - pages_over  # pages of the 4 MiB tmpfs taken by a file
    code = ("from sc3d_train.data.dataset import ShardDataset\nfrom sc3d_train.data.loader import make_loader\n"
            f"try:\n    next(iter(make_loader(ShardDataset({str(sample_shards)!r}, 'train'), 4, seed=0, workers=2)))\n"
            "except Exception as e:\n    print(type(e).__name__, e)\nelse:\n    print('no error')\n")
    res = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=4m tmpfs /dev/shm && "
                          f"dd if=/dev/zero of=/dev/shm/fill bs=4096 count={fill} 2>/dev/null && "
                          f"{sys.executable} -c \"$0\"", code], capture_output=True, text=True)
    out = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else res.stderr
    assert out.startswith("OSError ") and "/dev/shm" in out and "--workers" in out, res.stdout + res.stderr


def test_a_loader_worker_killed_mid_run_stops_fit_in_one_line_naming_the_checkpoint(sample_shards, tmp_path,
                                                                                  monkeypatch):
    """``kill -9`` of a loader worker (as the out-of-memory killer does) ended ``fit`` in PyTorch's
    RuntimeError traceback, raised by its SIGCHLD handler wherever the main process was (in
    backward). It must be one line saying a loader worker died and naming the last good
    checkpoint and --resume, as Ctrl-C does. The worker kills itself when given the fifth task
    (batches 16-19), after the checkpoint of step 4."""
    from sc3d_cli.train import main
    from sc3d_train.data import loader

    assemble = loader._RingBatches.__getitem__

    def dies_at_task_16(self, key):
        if key[0] >= 16 and loader.torch.utils.data.get_worker_info() is not None:
            os.kill(os.getpid(), signal.SIGKILL)
        return assemble(self, key)

    monkeypatch.setattr(loader._RingBatches, "__getitem__", dies_at_task_16)
    out = tmp_path / "run"
    res = run_cli(main, ["fit", "--shards", sample_shards, "--out", out, "--steps", "40", "--checkpoint-every", "4",
                         "--workers", "1", *TINY_FIT], expect_exit=1)
    error = one_error(res.output)
    assert "loader worker" in error and "killed by signal" in error and "--resume" in error, error
    assert str(out / "checkpoints") in error, error


def test_a_loader_worker_death_reported_during_a_checkpoint_write_is_raised_as_itself(tmp_path, monkeypatch):
    """PyTorch raises a dead worker's RuntimeError from its SIGCHLD handler wherever the main
    process is; where that is a write of ``torch.save`` (a checkpoint), torch.save turned it into
    "unexpected pos N vs M", which ``fit`` does not know as a worker's death: a traceback, and
    the temporary file left. It must come out as itself (then one line: ``worker_death``), the
    temporary file removed."""
    import io

    import torch

    from sc3d_train.loop import atomic_save

    died = RuntimeError("DataLoader worker (pid 123) is killed by signal: Killed. ")

    class DiesOnSecondWrite(io.BytesIO):
        writes = 0

        def write(self, data):
            self.writes += 1
            if self.writes == 2:
                raise died
            return super().write(data)

    monkeypatch.setattr(atomic_save, "create_new_file", lambda path: (path.write_bytes(b"partial"),
                                                                     DiesOnSecondWrite())[1])
    tmp = tmp_path / "last.pt.tmp"
    with pytest.raises(RuntimeError) as caught:
        atomic_save.save_atomically({"w": torch.zeros(1000)}, tmp, tmp_path / "last.pt")
    assert caught.value is died and not tmp.exists() and not (tmp_path / "last.pt").exists()
