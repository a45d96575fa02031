"""The manual: `docs/` rendered by mkdocs and served by the app at /help, from one source.

``reference`` expands the markers the pages hold (settings, commands, the API, benchmarks) from
the code; ``pages`` renders a page for /help with the nav of ``mkdocs.yml``; ``hook`` is the
mkdocs hook that runs the same expansion at build time.
"""
