"""Pictures (matplotlib figures, PIL images) written whole or not at all: encoded in memory, then
``shards.atomic_write_bytes`` (a temporary file created anew, renamed over ``path``), so a reader
never sees half a picture and a symbolic link standing at ``path`` is replaced, not written
through. The format follows ``path``'s extension, as ``savefig`` and ``Image.save`` would choose it."""
from __future__ import annotations

import io
from pathlib import Path

from sc3d_data.io.shards import atomic_write_bytes


def write_figure(fig, path: Path, dpi: int, metadata: dict | None = None) -> None:
    """Matplotlib figure ``fig`` to ``path`` at ``dpi`` (PNG unless the extension names another
    format matplotlib writes: ``.pdf``, ``.svg``, ``.jpg`` ...), with ``metadata`` (``savefig``'s:
    a PNG's text chunks, which PIL reads back as ``Image.info``)."""
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format=Path(path).suffix[1:].lower() or "png", metadata=metadata)
    atomic_write_bytes(Path(path), buf.getvalue())


def check_figure_format(path: Path) -> None:
    """``ValueError`` (matplotlib's own words) when :func:`write_figure` could not write ``path``'s
    format: called before a long computation whose picture it is (``check --png``), so that a
    name such as ``worst.txt`` is refused at once, not after the check has run."""
    from matplotlib.backend_bases import FigureCanvasBase

    fmt = Path(path).suffix[1:].lower() or "png"
    supported = FigureCanvasBase.get_supported_filetypes()
    if fmt not in supported:
        raise ValueError(f"Format {fmt!r} is not supported (supported formats: {', '.join(sorted(supported))})")


def write_image(image, path: Path) -> None:
    """PIL image ``image`` to ``path`` in the format of its extension (``ValueError`` from PIL for
    an extension it cannot write, before anything is written)."""
    from PIL import Image

    fmt = Image.registered_extensions().get(Path(path).suffix.lower())
    if fmt is None:
        raise ValueError(f"unknown file extension: {Path(path).suffix!r}")
    buf = io.BytesIO()
    image.save(buf, format=fmt)
    atomic_write_bytes(Path(path), buf.getvalue())
