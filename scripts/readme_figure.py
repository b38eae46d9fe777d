"""The README's figure: a finished job's class probabilities per run, grouped by true state.

The same figure opens the job's damage report (``report/index.html``, "Class probabilities per
run"); this writes it as a PNG file for pages that cannot embed the report.

Usage::

    .venv/bin/python scripts/readme_figure.py out/demo [--out docs/img/demo_probabilities.png]

``out/demo`` is the folder of ``make demo`` (``bayesdoor demo --quick --out out/demo``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("job", type=Path, help="a finished job's folder")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "docs" / "img" / "demo_probabilities.png"
    )
    args = parser.parse_args(argv)
    classification = args.job / "classify" / "classification.json"
    if not classification.is_file():
        parser.error(f"{classification} does not exist: pass the folder of a finished job")
    from bayesdoor.report import probability_bars
    from bayesdoor.systems import HEALTHY

    payload = json.loads(classification.read_text())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    healthy = payload.get("healthy_state", HEALTHY)
    args.out.write_bytes(probability_bars(payload["runs"], payload["classes"], healthy))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
