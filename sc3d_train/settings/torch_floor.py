"""The oldest torch sc3d loads checkpoints with: 2.6. Before it, ``torch.load(weights_only=True)``
could run code from a crafted file (CVE-2025-32434 affects 2.5.1 and earlier), and
``torch.serialization.safe_globals``, which checkpoint loading uses, is missing before 2.5.
Standard library only: ``scripts/setup.sh`` asks it about a torch it may keep, before sc3d is
installed."""
from __future__ import annotations

#: the first (major, minor) torch that loads a checkpoint without running code from it
SAFE_TORCH = (2, 6)


def torch_is_safe(version: str) -> bool:
    """Whether a torch ``version`` string (``2.13.0+cpu``, ``2.6.0a0+git``) is at least SAFE_TORCH."""
    try:
        major, minor = (int(x) for x in version.split("+")[0].split(".")[:2])
    except ValueError:
        return True  # an unparseable local build: let torch itself decide
    return (major, minor) >= SAFE_TORCH
