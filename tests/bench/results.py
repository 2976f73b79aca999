"""Where a bench's report goes: ``bench-results/<name>[_held_out].json`` unless told."""

from __future__ import annotations

import json
from pathlib import Path


def save_report(report: dict, name: str, held_out: bool = False,
                path: str | None = None) -> Path:
    """Write ``report`` as JSON and say where (with the seconds it took, when it has them)."""
    out = Path(path or f"bench-results/{name}{'_held_out' if held_out else ''}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2))
    took = f" ({report['seconds']:.0f} s)" if "seconds" in report else ""
    print(f"\nWritten {out}{took}")
    return out
