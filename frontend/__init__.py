"""The operator dashboard: static files (HTML, ES modules, CSS, vendored uPlot) served by `isorig serve` at /."""

from pathlib import Path

STATIC_DIR = Path(__file__).resolve().parent / "static"
