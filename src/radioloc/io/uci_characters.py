"""Reader of the UCI Character Trajectories pen-tip data (``trajectories_train.mat``).

Each sequence is a 3 x T array of pen-tip x velocity, y velocity and force (200 Hz, units not
documented; see the data folder's SOURCE.md). Positions are the cumulative sums of the two
velocity rows, after dropping the leading all-zero columns.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from radioloc.core.errors import DataUnavailable, InputError

__all__ = ["load_pen_positions", "resampled_tracks", "FILE_NAME"]

FILE_NAME = "trajectories_train.mat"


@lru_cache(maxsize=4)
def _load(path: str) -> tuple[tuple[np.ndarray, ...], np.ndarray, tuple[str, ...]]:
    import scipy.io

    mat = scipy.io.loadmat(path)
    try:
        seqs = mat["xtrain"].ravel()
        labels = np.asarray(mat["ytrain"]).ravel().astype(int)
        key = tuple(str(np.asarray(k).ravel()[0]) for k in np.asarray(mat["key"]).ravel())
    except KeyError as exc:
        raise InputError(f"{path}: missing variable {exc} (expected xtrain, ytrain, key)") from None
    positions = []
    for i, seq in enumerate(seqs):
        arr = np.asarray(seq, dtype=float)
        if arr.ndim != 2 or arr.shape[0] < 2:
            raise InputError(f"{path}: xtrain[{i}] has shape {arr.shape}, expected 3 x T")
        moving = np.flatnonzero(np.any(arr[:2] != 0.0, axis=0))
        start = moving[0] if moving.size else 0
        positions.append(np.cumsum(arr[:2, start:], axis=1).T)
    return tuple(positions), labels, key


def load_pen_positions(folder: Path | str) -> tuple[list[np.ndarray], np.ndarray, tuple[str, ...]]:
    """Pen-tip positions of every sequence.

    Parameters
    ----------
    folder : path
        The ``uci-character-trajectories`` folder holding ``trajectories_train.mat``.

    Returns
    -------
    positions : list of arrays (T_i, 2)
        Cumulative sums of the velocity rows (arbitrary units), leading zeros removed.
    labels : array of int
        Class of each sequence, 1-based index into ``key``.
    key : tuple of str
        The class letters.
    """
    path = Path(folder) / FILE_NAME
    if not path.is_file():
        raise DataUnavailable(f"{path}: file not found (UCI character trajectories)")
    pos, labels, key = _load(str(path))
    return [p.copy() for p in pos], labels.copy(), key


def resampled_tracks(folder: Path | str, n_samples: int, stride: int,
                     scale: float) -> np.ndarray:
    """Every sequence long enough, cut to ``n_samples`` samples taken every ``stride``-th.

    Parameters
    ----------
    folder : path
        The ``uci-character-trajectories`` folder.
    n_samples : int
        Samples kept per sequence.
    stride : int
        Keep every ``stride``-th 200 Hz sample.
    scale : float
        Factor applied to the positions (their unit is undocumented).

    Returns
    -------
    ndarray, shape (n_sequences, n_samples, 2)
        Positions ``(x, y)`` of every sequence with at least ``(n_samples - 1) stride + 1``
        samples.

    Raises
    ------
    DataUnavailable
        The file is absent.
    InputError
        Bad ``n_samples``/``stride`` or no sequence long enough.
    """
    if n_samples < 1 or stride < 1:
        raise InputError(f"n_samples, stride: must be >= 1, got {n_samples}, {stride}")
    pos, _, _ = load_pen_positions(folder)
    need = (n_samples - 1) * stride + 1
    keep = [p[:need:stride] for p in pos if p.shape[0] >= need]
    if not keep:
        raise InputError(f"n_samples: no sequence has {need} samples for stride {stride}")
    return scale * np.stack(keep)
