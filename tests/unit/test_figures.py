"""The manual's bench figures are the last bench run's (``tests.bench.figures``): a figure
edited by hand in a rendered block fails here."""

from __future__ import annotations

import re

import pytest

from tests.bench import figures


def test_every_figures_block_is_what_the_bench_results_render() -> None:
    stale = figures.stale_pages()
    assert not stale, (f"{[str(p.relative_to(figures.ROOT)) for p in stale]}: figures not "
                       "bench-results' (python -m tests.bench.figures renders them)")


def test_the_manual_shows_the_rendered_figures() -> None:
    """Each renderer's block is on a page of the manual or the README (the speed figures in
    *developing*, the turning figures in *how it works*, their summary in the README)."""
    text = "".join(p.read_text() for p in figures.pages())
    for name in figures.RENDER:
        assert f"<!-- figures: {name} -->" in text, name


def test_a_figure_edited_by_hand_is_caught() -> None:
    page = (figures.DOCS / "developing.md").read_text()
    rendered = figures.core_throughput()
    edited = page.replace(rendered, rendered.replace("x |", "0x |", 1))
    assert edited != page
    assert figures.render_page(edited) == page


def test_an_unknown_block_is_named() -> None:
    with pytest.raises(KeyError, match="no figures named 'speed'"):
        figures.render_page("<!-- figures: speed -->\nold\n<!-- /figures -->")


# A measured figure typed into a page's prose drifts from the code it measured; what the
# benches measure is rendered in blocks. What this finds outside a block must be a setting, a
# unit or a test's input, named here with what it is.
MEASURED = re.compile(r"(?<![\w.])\d+\.\d+ ?(?:um|us|ms|%|x|frames/s|measurements/s|"
                      r"messages/s|MiB|MB/s)(?![\w/])")
NOT_MEASURED = {
    "0.1 um": "the registers' and AQDEF's resolution",
    "6.45 um": "the simulated sensor's pixel pitch",
    "6.5 um": "the default uncertainty limit (measurement.max_uncertainty_mm)",
    "1.5 x": "MQTT's keep-alive rule",
    "0.01 %": "packet loss set in the fault suite",
    "0.1 %": "packet loss set in the fault suite",
    "0.2 %": "a test's tolerance on the focal length",
    "1.5 um": "the gauge's noise in the LinuxCNC loop test",
    "2.5 um": "the tool wear a part in the LinuxCNC loop test",
    "0.4 um": "the embedded default's simulated tool wear a minute",
    "0.8 um": "the embedded default's second simulated tool's wear a minute; the pin's "
              "taper a part in the LinuxCNC entries test",
    "1.2 um": "the insert's wear a part in the LinuxCNC entries test",
}


def figures_outside_blocks(text: str) -> list[str]:
    """The measured-looking figures of a page outside its rendered blocks and its code."""
    prose = re.sub(r"```.*?```", "", figures.BLOCK.sub("", text), flags=re.S)
    prose = re.sub(r"`[^`\n]*`", "", prose)
    return MEASURED.findall(prose)


def test_no_measured_figure_is_typed_into_the_manual() -> None:
    pages = figures.pages()
    typed = {p.name: sorted({f for f in figures_outside_blocks(p.read_text())
                             if f not in NOT_MEASURED}) for p in pages}
    typed = {k: v for k, v in typed.items() if v}
    assert not typed, (f"{typed}: measured figures outside a rendered block (render them from "
                       "a bench's results, or name them in NOT_MEASURED if they are settings)")


def test_a_figure_typed_into_prose_is_caught() -> None:
    page = "A tracked frame takes 2.76 ms.\n<!-- figures: x -->\n| 1.97 ms |\n<!-- /figures -->"
    assert figures_outside_blocks(page) == ["2.76 ms"]
    assert figures_outside_blocks("`--max-uncertainty-um 6.5` and 31.1x faster") == ["31.1x"]
