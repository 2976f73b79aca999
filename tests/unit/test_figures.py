"""The manual's bench figures are the last bench run's (``tests.bench.figures``): a figure
edited by hand in a rendered block fails here."""

from __future__ import annotations

import pytest

from tests.bench import figures


def test_every_figures_block_is_what_the_bench_results_render() -> None:
    stale = figures.stale_pages()
    assert not stale, (f"{[str(p.relative_to(figures.ROOT)) for p in stale]}: figures not "
                       "bench-results' (python -m tests.bench.figures renders them)")


def test_the_manual_shows_the_rendered_figures() -> None:
    """Each renderer's block is on a page of the manual (the speed figures in *developing*,
    the turning figures in *how it works*)."""
    text = "".join(p.read_text() for p in sorted(figures.DOCS.glob("*.md")))
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
