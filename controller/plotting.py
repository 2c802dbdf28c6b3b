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


def save_figure(fig, path: str, *, dpi: int = 110) -> None:
    """Write ``fig`` to ``path`` (its directory made) and close it, whatever happens."""
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise BadInput(path, None, f"cannot write: {exc.strerror or exc}") from None
    finally:
        pyplot().close(fig)
