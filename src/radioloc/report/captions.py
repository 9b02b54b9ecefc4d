"""Figure captions: ``captions.json`` ``{file stem: caption}`` beside the figures.

:func:`radioloc.report.style.save` records each figure's caption here as it writes the PNG,
and the report (:mod:`radioloc.report.html`) shows it under the figure. A caption says what
is plotted: for a reproduced figure it quotes the paper's caption (``Fig. N of paper P:
...``) and names what ours adds; for a figure of our own, one sentence. A caption that only
repeats the file name (``error_cdf`` -> ``Error cdf``) is refused.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from radioloc.core.errors import ConfigError

#: File holding the captions of the figures of one folder.
CAPTIONS_FILE = "captions.json"


def _words(text: str) -> str:
    """Lower-case letters and digits of ``text``, one space between words."""
    return " ".join(re.findall(r"[a-z0-9]+", text.lower()))


def is_file_name(caption: str, stem: str) -> bool:
    """True when ``caption`` says no more than the file name ``stem`` (empty, or the same
    words once case, ``_``, ``-`` and punctuation are set aside, with or without a leading
    ``figN``).

    Parameters
    ----------
    caption : str
    stem : str
        File name without its suffix.

    Returns
    -------
    bool
    """
    words = _words(caption)
    bare = _words(re.sub(r"^fig\d+[a-z]?_?", "", stem))
    return not words or words in (_words(stem), bare)


def read_captions(folder: Path | str) -> dict[str, str]:
    """The captions recorded in ``folder`` (``{}`` without a readable ``captions.json``).

    Parameters
    ----------
    folder : path

    Returns
    -------
    dict of str to str
    """
    path = Path(folder) / CAPTIONS_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
        return {str(k): str(v) for k, v in data.items()}
    except (ValueError, AttributeError):
        return {}


def record_caption(figure_path: Path | str, caption: str) -> Path:
    """Add (or replace) the caption of the figure file ``figure_path`` in its folder's
    ``captions.json`` (written atomically).

    Parameters
    ----------
    figure_path : path
        The figure file.
    caption : str
        What the figure shows.

    Returns
    -------
    Path
        The ``captions.json`` written.

    Raises
    ------
    ConfigError
        The caption is empty or repeats the file name (:func:`is_file_name`).
    """
    from radioloc.core.atomic import atomic_write_text

    figure_path = Path(figure_path)
    caption = " ".join(str(caption).split())
    if is_file_name(caption, figure_path.stem):
        raise ConfigError(f"caption of {figure_path.name}: {caption!r} repeats the file name; "
                          "say what the figure shows")
    captions = read_captions(figure_path.parent)
    captions[figure_path.stem] = caption
    return atomic_write_text(figure_path.parent / CAPTIONS_FILE,
                             json.dumps(dict(sorted(captions.items())), indent=1) + "\n")
