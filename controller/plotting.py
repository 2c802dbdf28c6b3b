"""Writing a matplotlib page: one place for the survey's histograms, the cleaner's map and the
production report (no display on a farm PC or in CI; a path that cannot be written is BadInput)."""
from __future__ import annotations

from pathlib import Path

from controller.errors import BadInput


def pyplot():
    """matplotlib.pyplot on the Agg backend."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def check_figure_name(path: str, option: str) -> None:
    """Before any work: a page's name must say a format matplotlib writes (none: PNG)."""
    from matplotlib.backend_bases import FigureCanvasBase
    kinds = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(path).suffix[1:].lower()
    if suffix and suffix not in kinds:
        raise BadInput(path, option, f"cannot draw a .{suffix} picture (formats: {', '.join(sorted(kinds))})")


def save_figure(fig, path: str, *, dpi: int = 110) -> None:
    """Write ``fig`` to ``path`` (its directory made) and close it, whatever happens."""
    from controller.atomic_files import replace_atomically
    try:
        # the format from the name asked for: the file is written under another name first
        replace_atomically(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=Path(path).suffix[1:].lower() or "png"))
    finally:
        pyplot().close(fig)
