"""The next batch on its way to the GPU while the current step runs.

On CUDA, :class:`DevicePrefetcher` issues batch k+1's host-to-device copy (from the loader's
page-locked memory) and its expansion (``batch_format.expand_batch``: uint8 to float, per
view, on the device) on a side stream as soon as batch k is handed out; the main stream waits
for that stream only when it takes batch k+1, and the batch's tensors are marked as used by the
main stream so their memory is not reused early. Off CUDA the batches are made when asked for
(nothing to overlap). Prefetching reads the loader one batch ahead; the batches and their order
are unchanged, and no random number is drawn. An error of the loader while reading ahead is
raised when its batch is asked for, as off CUDA: the batch before it is handed out and trained
(it was lost, and with it a checkpoint due after it)."""
from __future__ import annotations

from typing import Callable, Iterator

import torch


class DevicePrefetcher:
    """Iterator over ``to_device(batch)`` for the batches of ``batches`` (dicts of host
    tensors and other values) on ``device``."""

    def __init__(self, batches: Iterator[dict], to_device: Callable[[dict], dict], device: torch.device):
        self.batches, self.to_device = batches, to_device
        self.stream = torch.cuda.Stream(device) if device.type == "cuda" else None
        self.pending: tuple[dict, dict] | None = None  # (host batch, device batch) issued ahead
        self.error: Exception | None = None  # the loader's, while reading ahead: raised on the next call

    def __iter__(self):
        return self

    def _issue(self) -> tuple[dict, dict]:
        host = next(self.batches)
        with torch.cuda.stream(self.stream):
            return host, self.to_device(host)

    def __next__(self) -> dict:
        if self.stream is None:
            return self.to_device(next(self.batches))
        if self.error is not None:
            error, self.error = self.error, None
            raise error
        if self.pending is None:
            self.pending = self._issue()
        _, batch = self.pending  # the host batch stays referenced until its copy was waited for
        main = torch.cuda.current_stream(self.stream.device)
        main.wait_stream(self.stream)
        for v in batch.values():
            if torch.is_tensor(v) and v.is_cuda:
                v.record_stream(main)
        try:
            self.pending = self._issue()
        except StopIteration:
            self.pending = None
        except Exception as e:  # noqa: BLE001 - raised when its batch is asked for (module doc)
            self.pending, self.error = None, e
        return batch
