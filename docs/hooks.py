"""mkdocs hooks: show the Sphinx roles of the docstrings (``:class:`Track```) as plain code,
and write the kinds table (:func:`radioloc.core.kinds.markdown_table`) where a page asks for
it with :data:`KINDS_MARKER`."""

import re

_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):(?=<code>)")
#: A line of a page replaced by the table of the measurement kinds the registry declares.
KINDS_MARKER = "<!-- kinds table: generated from radioloc.core.kinds -->"


def on_page_markdown(markdown, **kwargs):
    if KINDS_MARKER not in markdown:
        return markdown
    from radioloc.core.kinds import markdown_table

    return markdown.replace(KINDS_MARKER, markdown_table().rstrip("\n"))


def on_page_content(html, **kwargs):
    return _ROLE.sub("", html)
