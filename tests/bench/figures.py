"""The manual's bench figures, rendered from ``bench-results/`` (what ``make bench`` wrote, with
its machine, commit and date), so that a figure in the docs is always the last run's.

A page holds a rendered block between ``<!-- figures: NAME -->`` and ``<!-- /figures -->``;
``python -m tests.bench.figures`` writes every block again (``make bench`` runs it last),
``--check`` only says which differ (``tests/unit/test_figures.py`` runs that: a figure edited
by hand in a block fails it).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "bench-results"
DOCS = ROOT / "docs"
BLOCK = re.compile(r"(<!-- figures: (?P<name>[a-z_]+) -->\n)(?P<body>.*?)(<!-- /figures -->)",
                   re.S)


def _load(name: str) -> dict:
    return json.loads((RESULTS / f"{name}.json").read_text())


def _measured(run: dict) -> str:
    dirty = ", uncommitted changes" if run.get("dirty") else ""
    return (f"*Measured {run['date'][:10]} on {run['machine'].split(',')[1].strip()} "
            f"({run['machine'].split(',')[0]}), commit `{run['commit']}`{dirty}.*")


def core_throughput() -> str:
    """The measurement core on one core against the fair plain Steger of the same run."""
    d = _load("core_throughput")
    plain = d["extractors"]["plain_steger"]["ms_per_frame"]
    names = {"axis": "default, `axis`", "geometric": "default, `geometric`",
             "axis, wide sheet": f"sheet {d['wide_rig']['sheet_sigma_mm']} mm, "
             f"{d['wide_rig']['speckle_grain_px']} px speckle grains, `axis`"}
    rows = ["| rig, method | frames/s on one core | median frame | first frame of a shaft | "
            "plain Steger / median frame | mean \\|error\\| per frame |",
            "|---|---:|---:|---:|---:|---:|"]
    for key, v in d["core"].items():
        err = "every frame refused as uncertain" if v["mean_abs_error_um"] is None \
            else f"{v['mean_abs_error_um']:.2f} um"
        rows.append(f"| {names.get(key, key)} | {v['fps_one_core']:.1f} | "
                    f"{v['median_frame_ms']:.2f} ms | {v['first_frame_ms']:.1f} ms | "
                    f"{v['plain_steger_vs_median_frame']:.1f}x | {err} |")
    rc = d["reflection_check"]
    return "\n".join([
        f"{d['shafts']} shafts x {d['frames_per_shaft']} frames of "
        f"{d['image_size'][0]}x{d['image_size'][1]}, {d['runs']} runs, medians; the plain "
        f"Steger {plain:.1f} ms a frame in the same run; a frame checked for a reflection "
        f"{rc['median_frame_ms']:.2f} ms.", "", *rows, "", _measured(d["run"])])


def core_stages() -> str:
    """Where a tracked ``axis`` frame's time goes, and what a reflection check adds."""
    d = _load("core_throughput")
    st, rc = d["stages_ms"], d["reflection_check"]
    tracked = d["core"]["axis"]["median_frame_ms"]
    rows = ["| stage | ms per frame |", "|---|---:|"]
    rows += [f"| {name} | {ms:.3f} |" for name, ms in st.items()]
    return "\n".join([
        f"A frame checked for a reflection: {rc['median_frame_ms']:.2f} ms, "
        f"{rc['median_frame_ms'] / tracked:.1f} tracked frames. Where a tracked `axis` frame's "
        "time goes (each stage timed one call at a time, so the total is a little above the "
        "median frame):", "", *rows, "", _measured(d["run"])])


def core_extractors() -> str:
    """The extractors on the core bench's frames, through the same triangulation and fit."""
    d = _load("core_throughput")
    names = {"ours": "ours (tracked band, compiled Steger, rejection, chains, curvature "
                     "correction)",
             "plain_steger": "plain Steger over the whole frame (as above)",
             "plain_steger_pruned": "the same, the eigenvector only where the strength test "
                                    "passes",
             "grey_centroid": "grey centroid per column (pixels above half the peak)"}
    rows = ["| extractor | frames | ms per frame | plain Steger / this | "
            "mean \\|error\\| per frame | failed |", "|---|---:|---:|---:|---:|---:|"]
    for key, v in d["extractors"].items():
        rows.append(f"| {names.get(key, key)} | {v['frames']} | {v['ms_per_frame']:.2f} | "
                    f"{v['plain_vs_this']:.1f} | {v['mean_abs_error_um']:.1f} um | "
                    f"{v['failed']} |")
    return "\n".join([*rows, "", _measured(d["run"])])


def service_throughput() -> str:
    """``serve`` at 100 fps: the embedded default and a fixed shaft, region on and off."""
    rows = ["| run | region of interest | measurements/s | frames dropped | "
            "registers median / p99 | CPU | with two polling clients: p99, REST p99, "
            "Modbus p99 |", "|---|:---:|---:|---:|---:|---:|---:|"]
    runs = []
    for name, what in (("service_throughput_embedded", "the embedded default, 100 fps"),
                       ("service_throughput_100fps", "a fixed 30 mm shaft, 100 fps"),
                       ("service_throughput_200fps", "a fixed 30 mm shaft, 200 fps")):
        if not (RESULTS / f"{name}.json").exists():
            continue
        d = _load(name)
        runs.append(d["run"])
        for r in d["results"]:
            c = r["with_clients"]
            rows.append(
                f"| {what} | {'on' if r['roi'] else 'off'} | {r['measurements_per_s']:.1f} | "
                f"{r['camera_dropped']} | {r['latency_median_ms']:.1f} / "
                f"{r['latency_p99_ms']:.1f} ms | {r['service_cpu_pct']:.0f} % | "
                f"{c['latency_p99_ms']:.1f} / {c['client_rest']['p99_ms']:.0f} / "
                f"{c['client_modbus']['p99_ms']:.0f} ms |")
    return "\n".join([*rows, "", *dict.fromkeys(_measured(r) for r in runs)])


def turning_service() -> str:
    """The service's frame path on turning surfaces: the tuning set and the held-out one."""
    def num(x: float | None, fmt: str) -> str:
        return "-" if x is None else fmt.format(x)

    out = []
    for name, what in (("turning_service", "Tuning set"),
                       ("turning_service_held_out", "Held out (scored once)")):
        path = RESULTS / f"{name}.json"
        if not path.exists():
            continue
        d = _load(name)
        scored = d["cases"][0]["frames"]
        out += [f"{what}: the last {scored} of {d['frames']} frames a case scored (the "
                f"run-out is learnt in the first), seeds "
                f"{', '.join(str(s) for s in d['seeds'])}, one row per case and seed.", "",
                r"| surface | seed | measured | mean / max \|error\| | max \|error\| / u "
                "| TIR error | RONt error | lobes (true) |",
                "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for r in d["cases"]:
            out.append(
                f"| {r['case']} | {r['seed']} | {r['measured']}/{r['frames']} | "
                f"{num(r['mean_abs_error_um'], '{:.2f}')} / "
                f"{num(r['max_abs_error_um'], '{:.1f}')} um | "
                f"{num(r['max_error_over_u'], '{:.1f}')} | "
                f"{num(r['tir_error_um'], '{:+.1f} um')} | "
                f"{num(r['ront_error_um'], '{:+.1f} um')} | "
                f"{num(r['lobes'], '{}')} ({r['lobes_true']}) |")
        out += ["", _measured(d["run"]), ""]
    return "\n".join(out).rstrip("\n")


RENDER: dict[str, Callable[[], str]] = {"core_throughput": core_throughput,
                                        "core_stages": core_stages,
                                        "core_extractors": core_extractors,
                                        "service_throughput": service_throughput,
                                        "turning_service": turning_service}


def render_page(text: str) -> str:
    """``text`` with every figures block rendered again."""
    def block(m: re.Match) -> str:
        name = m["name"]
        if name not in RENDER:
            raise KeyError(f"no figures named {name!r} (known: {', '.join(RENDER)})")
        return f"{m.group(1)}{RENDER[name]()}\n{m.group(4)}"

    return BLOCK.sub(block, text)


def stale_pages() -> list[Path]:
    """The pages whose figures blocks are not what the bench results render."""
    return [p for p in sorted(DOCS.glob("*.md")) if render_page(p.read_text()) != p.read_text()]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only say which pages differ")
    args = ap.parse_args()
    stale = stale_pages()
    if args.check:
        for p in stale:
            print(f"{p.relative_to(ROOT)}: its figures are not bench-results' "
                  "(python -m tests.bench.figures renders them)", file=sys.stderr)
        return 1 if stale else 0
    for p in stale:
        p.write_text(render_page(p.read_text()))
        print(f"rendered {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
