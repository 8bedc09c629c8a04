"""The figures of a benchmark: printed, and written as JSON where `--json` asks."""

import json
from pathlib import Path


def write_figures(figures: dict, path: Path | None) -> None:
    text = json.dumps(figures, indent=2, default=float)
    print(text)
    if path:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
