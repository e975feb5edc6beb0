"""``did_you_mean``: the one "did you mean" of a mistyped name (model, preset, input
strategy, config key), torch-free, for the one-line errors of docs/cli.md."""

from __future__ import annotations

import difflib
from collections.abc import Iterable

__all__ = ["did_you_mean"]


def did_you_mean(word: str, choices: Iterable[str], cutoff: float = 0.6) -> str:
    """``" (did you mean 'x'?)"`` (or ``'x' or 'y'``) for the choices closest to ``word``
    (``difflib.get_close_matches``, case-insensitive, ``cutoff`` its similarity bound in
    [0, 1]; else the choices that begin with ``word``: a name cut short), else ``""``.

    Deterministic: the same word and choices give the same text.
    """
    options = list(dict.fromkeys(str(c) for c in choices))
    by_lower = {c.lower(): c for c in options}
    key = str(word).lower()
    close = difflib.get_close_matches(key, list(by_lower), n=2, cutoff=cutoff)
    if not close and len(key) >= 2:  # a name cut short ("syn" for "synthetic")
        close = sorted(c for c in by_lower if c.startswith(key))[:2]
    if not close:
        return ""
    return " (did you mean " + " or ".join(f"'{by_lower[c]}'" for c in close) + "?)"
