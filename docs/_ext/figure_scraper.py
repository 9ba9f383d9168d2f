"""A sphinx-gallery image scraper for the figures the library returns.

The plotting functions of ``resection`` and ``selfillum`` build
:class:`matplotlib.figure.Figure` objects without pyplot (no global figure state), so the
gallery's default matplotlib scraper, which asks pyplot, does not see them. This one
saves every ``Figure`` that a code block of an example left in its variables (directly, or
in a list, tuple or dict) and that was not shown before; pyplot's own figures are left to
the default scraper.
"""

from __future__ import annotations

from matplotlib.figure import Figure

_SEEN = "__scraped_figure_ids__"


def _figures(value):
    if isinstance(value, Figure):
        yield value
    elif isinstance(value, list | tuple):
        for item in value:
            if isinstance(item, Figure):
                yield item
    elif isinstance(value, dict):
        for item in value.values():
            if isinstance(item, Figure):
                yield item


def scrape(block, block_vars, gallery_conf):
    from sphinx_gallery.scrapers import figure_rst

    namespace = block_vars["example_globals"]
    seen = namespace.setdefault(_SEEN, set())
    paths = []
    for name, value in list(namespace.items()):
        if name.startswith("__"):
            continue
        for fig in _figures(value):
            if id(fig) in seen or fig.canvas.manager is not None:  # pyplot's: not ours
                continue
            seen.add(id(fig))
            path = next(block_vars["image_path_iterator"])
            fig.savefig(path, dpi=fig.dpi)
            paths.append(path)
    return figure_rst(paths, gallery_conf["src_dir"])


def _get_sg_image_scraper():
    return scrape
