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
import statistics
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


def _present(*runs: tuple[str, str]) -> list[tuple[str, dict]]:
    """(caption, results) of each run whose results file is there (a held-out set is scored
    by hand, so its file may not be)."""
    return [(what, _load(name)) for name, what in runs if (RESULTS / f"{name}.json").exists()]


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
    for what, d in _present(("turning_service", "Tuning set"),
                            ("turning_service_held_out",
                             "Held out (never tuned on, scored at the end of a piece of work)")):
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


def turning_summary() -> str:
    """The held-out turning set per case (its seeds together), for the front door: refusals,
    the diameters' error against the concentric case's, the run-out's and the form's errors."""
    d = _load("turning_service_held_out")
    cases: dict[str, list[dict]] = {}
    for r in d["cases"]:
        cases.setdefault(r["case"], []).append(r)

    def worst(rows: list[dict], key: str) -> str:
        vals = [r[key] for r in rows if r[key] is not None]
        return "-" if not vals else f"{max(vals, key=abs):+.1f} um"

    out = [r"| surface | refused | mean \|error\| | TIR error | RONt error | lobes found |",
           "|---|---:|---:|---:|---:|---:|"]
    for case, rows in cases.items():
        measured = [r["mean_abs_error_um"] for r in rows if r["mean_abs_error_um"] is not None]
        lobes = ", ".join(f"{r['lobes'] if r['lobes'] is not None else '-'} of "
                          f"{r['lobes_true']}" for r in rows)
        out.append(f"| {case} | {sum(r['frames'] - r['measured'] for r in rows)} of "
                   f"{sum(r['frames'] for r in rows)} | "
                   f"{_um(max(measured) if measured else None)} | {worst(rows, 'tir_error_um')} | "
                   f"{worst(rows, 'ront_error_um')} | {lobes} |")
    seeds = ", ".join(str(s) for s in d["seeds"])
    return "\n".join([f"Held-out turning set (never tuned on; seeds {seeds}; the worst seed "
                      "shown), "
                      f"{d['cases'][0]['frames']} frames a case and seed at 100 frames/s:", "",
                      *out, "", _measured(d["run"])])


def _um(x: float | None, fmt: str = "{:.2f}") -> str:
    return "-" if x is None or x != x else fmt.format(x) + " um"


def paper_comparison() -> str:
    """The paper's comparison (its Tables 3-10) on the simulated rig, per frame."""
    d = _load("paper_comparison")
    names = {"ellipse": "ellipse (Eq. 10-11)", "circle": "circle (Kasa)",
             "paper": "paper (constrained centre)", "geometric": "geometric",
             "axis": "**axis** (default)"}
    rows = [r"| method | mean \|error\| | bias | std | frames refused |",
            "|---|---:|---:|---:|---:|"]
    for m, v in d["all"].items():
        rows.append(f"| {names.get(m, m)} | {_um(v['mean_abs_error_um'], '{:.1f}')} | "
                    f"{_um(v['bias_um'], '{:.1f}')} | {_um(v['std_um'], '{:.1f}')} | "
                    f"{v['failed']} of {v['frames'] + v['failed']} |")
    methods = list(d["all"])
    shafts = [f"| shaft | {' | '.join(methods)} |", "|---|" + "---:|" * len(methods)]
    for s, v in d["shafts"].items():
        shafts.append(f"| {s} | " + " | ".join(_um(v[m]["mean_abs_error_um"], "{:.1f}")
                                             for m in methods) + " |")
    ang = d["angles"]
    cond = ["| condition | `geometric` | `axis` | `axis` frames refused |", "|---|---:|---:|---:|"]
    for what, v in [*((f"triangulation {float(a):g} degrees (Tables 7, 8)", v)
                      for a, v in ang.items()),
                    ("the paper's added noise (Tables 9, 10)", d["added_noise"])]:
        cond.append(f"| {what} | {_um(v['geometric']['mean_abs_error_um'], '{:.1f}')} | "
                    f"{_um(v['axis']['mean_abs_error_um'], '{:.1f}')} | "
                    f"{v['axis']['failed']} |")
    t = d["timing_ms_median"]
    timing = ", ".join(f"`{m}` {v:.0f} ms" for m, v in t.items())
    return "\n".join([
        f"{d['frames_per_diameter']} frames per diameter, seed {d['seed']}; per frame, "
        "every frame measured as the paper did (no uncertainty limit):", "", *rows, "",
        "Per shaft, mean \\|error\\| per frame:", "", *shafts, "",
        f"Other conditions, {max(2, d['frames_per_diameter'] // 2)} frames per diameter, mean "
        "\\|error\\| per frame:", "", *cond, "",
        f"A frame searched in full (no previous frame), median: {timing}.", "",
        _measured(d["run"])])


def beyond_paper() -> str:
    """The methods and fusion over the bench's twelve conditions."""
    d = _load("beyond_paper")
    rows = [r"| method | mean \|error\| per frame | bias | std | std(error / uncertainty) |",
            "|---|---:|---:|---:|---:|"]
    for m, v in d["methods"].items():
        name = f"**{m}**" if m == "axis" else m
        rows.append(f"| {name} | {_um(v['mean_abs_error_um'])} | {_um(v['bias_um'])} | "
                    f"{_um(v['std_um'])} | {v['z_std']:.2f} |")
    f = d["fusion"]
    return "\n".join([
        f"Arcs of {d['arc_deg'][0]:.0f}-{d['arc_deg'][1]:.0f} degrees; `axis` "
        f"{d['axis_gain_vs_geometric']:.1f}x better than `geometric` and "
        f"{d['axis_gain_vs_paper']:.1f}x than `paper` per frame.", "", *rows, "",
        f"Fusing each condition's frames (`axis`): one frame {_um(f['single_mean_abs_um'])}, "
        f"fused {_um(f['fused_mean_abs_um'])}, **{f['gain']:.1f}x**; after a master check, "
        f"{_um(f['single_mean_abs_mastered_um'])} -> {_um(f['fused_mean_abs_mastered_um'])} "
        f"({f['gain_mastered']:.1f}x: the master's own fused error is added to every "
        "condition).", "", *_by_seed(d), _measured(d["run"])])


def _by_seed(d: dict) -> list[str]:
    """The same bench on other seeds, each its own shafts and frames, and their medians."""
    seeds = d.get("by_seed", {})
    if len(seeds) < 2:
        return []
    rows = [r"| seed | `axis` mean \|error\| | vs `geometric` | vs `paper` | fused | "
            "fusion | std(error / uncertainty) |", "|---:|---:|---:|---:|---:|---:|---:|"]
    rows += [f"| {k} | {_um(b['axis_mean_abs_um'])} | {b['vs_geometric']:.1f}x | "
             f"{b['vs_paper']:.1f}x | {_um(b['fused_mean_abs_um'])} | "
             f"**{b['fusion_gain']:.1f}x** | {b['z_std']:.2f} |" for k, b in seeds.items()]
    med = {k: statistics.median(b[k] for b in seeds.values())
           for k in ("vs_geometric", "vs_paper", "fusion_gain", "z_std")}
    return [f"On {len(seeds)} seeds: medians `axis` {med['vs_geometric']:.1f}x better than "
            f"`geometric` and {med['vs_paper']:.1f}x than `paper`, fusion "
            f"{med['fusion_gain']:.1f}x, std(error / uncertainty) {med['z_std']:.2f}.", "",
            *rows, ""]


FAMILY_NAMES = {"clean": "clean", "glints": "glints", "ghost": "ghost", "droplets": "droplets",
                "background": "stray light", "overexposed": "over-exposed",
                "feed_marks": "feed marks", "combined": "all at once"}


def robustness() -> str:
    """Every shop-floor disturbance family, development settings and held out."""
    out = []
    for what, d in _present(("robustness", "Development settings"),
                            ("robustness_held_out", "Held-out settings and seeds")):
        n = next(iter(d["families"].values()))["axis"]["frames"]
        out += [f"{what} (seeds {', '.join(map(str, d['seeds']))}, {n} frames a family):", "",
                r"| family | `axis` measured | mean / max \|error\| | frames > 20 um | "
                "`geometric` measured | `geometric` frames > 20 um |",
                "|---|---:|---:|---:|---:|---:|"]
        for fam, v in d["families"].items():
            a, g = v["axis"], v["geometric"]
            why = ", ".join(f"{k} {c}" for k, c in sorted(a["refused"].items()))
            measured = f"{a['measured_pct']:.1f} %" + (f" ({why})" if why else "")
            err = "-" if a["mean_abs_um"] != a["mean_abs_um"] else \
                f"{a['mean_abs_um']:.2f} / {a['max_abs_um']:.1f} um"
            out.append(f"| {FAMILY_NAMES.get(fam, fam)} | {measured} | {err} | "
                       f"{a['over_limit']} | {g['measured_pct']:.1f} % | {g['over_limit']} |")
        out += ["", _measured(d["run"]), ""]
    return "\n".join(out).rstrip("\n")


def rig_range() -> str:
    """``axis`` across rigs: sheet thickness and speckle, per frame and fused, beside the
    speckle's own floor, and how honest the uncertainty is."""
    out = []
    for what, d in _present(("rig_range", "Development rows"),
                            ("rig_range_held_out", "Held-out rows (other seeds and diameters)")):
        out += [f"{what}: diameters {', '.join(f'{x:g}' for x in d['diameters_mm'])} mm, "
                f"{d['frames']} frames each:", "",
                r"| rig (the rest at the defaults) | measured | mean \|error\| per frame | "
                "speckle floor | fused, mean / max | fused floor | z-score std | "
                "z, exact axis |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for row, v in d["rows"].items():
            out.append(f"| {row} | {v['measured_pct']:.1f} % | {_um(v['mean_abs_um'])} | "
                       f"{_um(v['floor_mean_abs_um'])} | {v['fused_mean_abs_um']:.2f} / "
                       f"{_um(v['fused_max_abs_um'])} | {_um(v['floor_fused_um'])} | "
                       f"{v['z_std']:.2f} | {v['z_std_exact_axis']:.2f} |")
        out += ["", _measured(d["run"]), ""]
    return "\n".join(out).rstrip("\n")


def _loop_rows(d: dict, held_out: bool) -> list[str]:
    rows = ["| case | law | parts out (worst seed) | longest run out (worst) | mean | sd | Cpk | "
            "offsets (reversed) | worst after an insert change |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for case, row in d["rows"].items():
        v = row["verdict"]
        mark = (" *(held out)*" if held_out else "") + \
            ("" if v["within_step"] else " *(wear per cycle beyond the largest step)*")
        for i, (law, r) in enumerate(row["laws"].items()):
            rows.append(f"| {case + mark if i == 0 else ''} | {law} | {r['out']:g} "
                        f"({r['out_max']}) | {r['run']:g} ({r['run_max']}) | "
                        f"{r['mean_um']:.1f} um | {r['sd_um']:.1f} um | {r['cpk']:.2f} | "
                        f"{r['writes']:g} ({r['reversals']:g}) | "
                        f"{_um(r['overshoot_um'], '{:.1f}')} |")
    return rows


def closed_loop() -> str:
    """The compensation laws on the virtual lathe under varied physics, the held-out cases
    beside, and which gains oscillate."""
    d = _load("closed_loop")
    rows = _loop_rows(d, held_out=False)
    held = ROOT / "bench-results" / "closed_loop_held_out.json"
    if held.exists():
        h = json.loads(held.read_text())
        rows += ["", f"Held out (other cases, seeds {', '.join(map(str, h['seeds']))}; scored "
                 "once):", "", *_loop_rows(h, held_out=True)]
    gains = list(next(iter(d["oscillation_map"].values())))
    osc = [f"| dead parts | {' | '.join(gains)} | limit | predictive, every gain |",
           "|---:|" + ":---:|" * len(gains) + "---:|:---:|"]
    for dead, m in d["oscillation_map"].items():
        cells = ["**oscillates**" if m[g] else "settles" for g in gains]
        pred = "oscillates" if any(d["oscillation_map_predictive"][dead].values()) \
            else "settles"
        osc.append(f"| {dead} | {' | '.join(cells)} | {d['limits'][dead]:.2f} | {pred} |")
    return "\n".join([
        f"{d['parts']} parts a case (8 h of continuous cutting), seeds "
        f"{', '.join(map(str, d['seeds']))}, medians; the gauge {d['gauge_sigma_um']:g} um a "
        f"part, outliers of {d['outlier_um']:g} um; largest step {d['max_step_um']:g} um:", "",
        *rows, "", "Gain against dead time, correcting every measurement (a step, no noise):",
        "", *osc, "", _measured(d["run"])])


def camera_throughput() -> str:
    """Frames received from the simulated camera on loopback, by receive path."""
    d = _load("camera_throughput")
    names = {"packet_socket": "packet socket (Aravis as root)",
             "udp_socket_auto": "UDP socket, buffer AUTO",
             "udp_socket_4MiB": "UDP socket, buffer fixed at 4 MiB"}
    rows = ["| receive path | frames/s | CPU of the receiving process |", "|---|---:|---:|"]
    for key, what in names.items():
        if key in d:
            rows.append(f"| {what} | {d[key]['fps_median']:.1f} | "
                        f"{d[key]['cpu_percent_median']:.1f} % of one core |")
    return "\n".join([
        f"1376x1024 Mono8, camera asked for {d['asked_fps']:g} fps, median of {d['runs']} runs "
        f"of {d['seconds']:g} s:", "", *rows, "", _measured(d["run"])])


def plant_publish() -> str:
    """What publishing costs the gauge, and fleets of gauges against one Mosquitto."""
    d = _load("plant_publish")
    c = d["cost"]
    meas, dec = c["measurement"]["median_cpu_us_per_message"], \
        c["decision"]["median_cpu_us_per_message"]
    rows = ["| fleet | run | delivered | measurements lost | decisions lost, out of order | "
            "Mosquitto CPU |", "|---|---:|---:|---:|---:|---:|"]
    broker_us = 0.0
    for key, f in d["fleets"].items():
        broker_us = max(broker_us, 1e6 * f["broker_cpu_s"]
                        / max(f["measurements_received"] + f["decisions_received"], 1))
        rows.append(f"| {key.replace('_', ' ')} x 10/s + a decision each 5 s | "
                    f"{f['seconds']:g} s | {f['delivered_per_s']:.1f} messages/s | "
                    f"{f['measurements_lost']} of {f['measurements_sent']} | "
                    f"{f['decisions_received']} of {f['decisions_sent']}, "
                    f"{f['decisions_out_of_order']} | "
                    f"{100 * f['broker_cpu_s'] / (f['seconds'] + 3):.1f} % of a core |")
    return "\n".join([
        "One publisher, 3 runs each, medians, CPU time of the gauge's process: a measurement "
        f"message (QoS 0) **{meas:.0f} us**; a decision (QoS 1, through the SQLite outbox, "
        f"acknowledged, removed) **{dec:.0f} us**; at 10 measurements/s "
        f"**{meas * 10 / 1e4:.2f} % of one core** (paho-mqtt from its own network thread: "
        f"{c['measurement_paho']['median_cpu_us_per_message']:.0f} us a message).", "",
        *rows, "", f"Mosquitto: {broker_us:.0f} us of CPU a message in and out.", "",
        _measured(d["run"])])


def principal_point() -> str:
    """How well each set of calibration views fixes the principal point and focal length."""
    d = _load("principal_point")
    rows = ["| board images | principal point std, x / y | focal length std | "
            "axis point moved |", "|---|---:|---:|---:|"]
    for name, s in d["sets"].items():
        rows.append(f"| {name} | {s['cx_std_px']:.2f} / {s['cy_std_px']:.2f} px | "
                    f"{100 * s['f_std_rel']:.3f} % | {s['axis_shift_mm']:.3f} mm |")
    return "\n".join([
        f"Ideal corners with {d['sigma_px']:g} px of noise (what the detector leaves on "
        f"rendered views), {d['trials']} draws each:", "", *rows, "", _measured(d["run"])])


def whole_part() -> str:
    """Four features on two tools under one controller per tool, tuning and held-out physics,
    and with a bound the deflection breaks."""
    runs = _present(("whole_part", "tuning physics"),
                    ("whole_part_held_out", "held-out physics, scored once"),
                    ("whole_part_tight_bound", "tuning physics, tool 2's features allowed "
                     "3 um apart (the deflection is 6): held"),
                    ("whole_part_taper15", "tuning physics, the slender end tapering 15 um "
                     "more over an insert's life, on its tool's one entry: held"),
                    ("whole_part_taper15_entries", "the same, the slender end on an offset "
                     "entry of its own"),
                    ("whole_part_held_out_taper15_entries", "held-out physics, the same, "
                     "scored once"),
                    ("whole_part_taper15_entries_skip0.3", "tuning physics, the slender end "
                     "on its own entry, each measurement skipped at 30 %"),
                    ("whole_part_held_out_taper15_entries_skip0.3", "held-out physics, the "
                     "same, scored once"))
    rows = ["| physics | feature | tolerance | parts out (worst seed) | mean | sd | Cpk "
            "(worst seed) |", "|---|---|---:|---:|---:|---:|---:|"]
    for what, d in runs:
        for i, f in enumerate(d["job"]["features"]):
            r = d["features"][str(f["number"])]
            entry = f" offset {f['entry']}" if f.get("entry") is not None else ""
            rows.append(f"| {what if i == 0 else ''} | {f['number']} {f['name']} "
                        f"(T{f['tool']}{entry}) "
                        f"| +-{f['tol_upper_mm'] * 1000:g} um | {r['out']:g} ({r['out_max']}) "
                        f"| {r['mean_um']:.1f} um | {r['sd_um']:.1f} um | {r['cpk']:.2f} "
                        f"({r['cpk_min']:.2f}) |")
    first = runs[0][1]
    return "\n".join([f"{first['parts']} parts, medians over seeds "
                      f"{', '.join(map(str, first['seeds']))} (held out: 900-904):", "",
                      *rows, "", _measured(first["run"])])


RENDER: dict[str, Callable[[], str]] = {"core_throughput": core_throughput,
                                        "core_stages": core_stages,
                                        "core_extractors": core_extractors,
                                        "service_throughput": service_throughput,
                                        "turning_service": turning_service,
                                        "turning_summary": turning_summary,
                                        "paper_comparison": paper_comparison,
                                        "beyond_paper": beyond_paper,
                                        "robustness": robustness,
                                        "rig_range": rig_range,
                                        "closed_loop": closed_loop,
                                        "camera_throughput": camera_throughput,
                                        "plant_publish": plant_publish,
                                        "principal_point": principal_point,
                                        "whole_part": whole_part}


def render_page(text: str) -> str:
    """``text`` with every figures block rendered again."""
    def block(m: re.Match) -> str:
        name = m["name"]
        if name not in RENDER:
            raise KeyError(f"no figures named {name!r} (known: {', '.join(RENDER)})")
        return f"{m.group(1)}{RENDER[name]()}\n{m.group(4)}"

    return BLOCK.sub(block, text)


def pages() -> list[Path]:
    """The pages that hold figures: the manual's and the README's."""
    return [*sorted(DOCS.glob("*.md")), ROOT / "README.md"]


def stale_pages() -> list[Path]:
    """The pages whose figures blocks are not what the bench results render."""
    return [p for p in pages() if render_page(p.read_text()) != p.read_text()]


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
